"""Emulated Depth Anything 3 for simulated recordings (DESIGN §4 "Emulated DA3", PRESETS.md).

`EmulatedDA3` implements the `DepthModel` protocol of the ONNX backend from simulator ground truth
plus DA3's failure modes, each a named `EmulatorParams` field, with Small/Base/Large presets.
The names are imported on first use (PEP 562): reading the presets (`params`) does not import the
emulator and OpenCV.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from runtime.lazy_exports import lazy_exports

_EXPORTS = {
    "BoxRoom": "models.emulated_da3.analytic",
    "BACKEND": "models.emulated_da3.emulator", "EmulatedDA3": "models.emulated_da3.emulator",
    "GroundTruthSource": "models.emulated_da3.groundtruth",
    "GroundTruthView": "models.emulated_da3.groundtruth",
    "PRESETS": "models.emulated_da3.params", "EmulatorParams": "models.emulated_da3.params",
    "make_params": "models.emulated_da3.params",
}

if TYPE_CHECKING:
    from models.emulated_da3.analytic import BoxRoom
    from models.emulated_da3.emulator import BACKEND, EmulatedDA3
    from models.emulated_da3.groundtruth import GroundTruthSource, GroundTruthView
    from models.emulated_da3.params import PRESETS, EmulatorParams, make_params

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = [
    "BACKEND",
    "BoxRoom",
    "EmulatedDA3",
    "EmulatorParams",
    "GroundTruthSource",
    "GroundTruthView",
    "PRESETS",
    "make_params",
]
