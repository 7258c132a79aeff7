"""`davio calibrate`: camera–IMU extrinsics and time offset from a recording (hand–eye bring-up + the
filter's online refinement) written as a Kalibr camchain, with the evidence (report, plots).

- `tools.calibrate.core`: runs the pipeline with T_IC withheld and collects the filter's calibration
  states over time, plus the rotation excitation of the gyro stream.
- `tools.calibrate.checks`: the refusal rules and their thresholds.
- `tools.calibrate.output`: the camchain, `<out stem>.report.json` and the convergence plots.
"""

from typing import TYPE_CHECKING

from runtime.lazy_exports import lazy_exports

# imported on first use (PEP 562): the `davio calibrate` options read the thresholds without the pipeline
_EXPORTS = {"Thresholds": "tools.calibrate.checks", "judge": "tools.calibrate.checks",
            "CalibrationRun": "tools.calibrate.core", "calibrate": "tools.calibrate.core"}

if TYPE_CHECKING:
    from tools.calibrate.checks import Thresholds, judge
    from tools.calibrate.core import CalibrationRun, calibrate

__all__ = ["CalibrationRun", "Thresholds", "calibrate", "judge"]


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
