"""The camera-IMU time-offset findings of the start-up's feed-forward windows and when one is adopted
(runtime.ffinit.time_offset_check finds them; runtime.startup.StartupManager applies an adopted offset)."""
from __future__ import annotations

from typing import Any

import numpy as np

from runtime.msckf.init_common import InitResult


class OffsetFindings:
    """Counts each window's finding in the start-up report (time_offset_findings, time_offset_first, and for
    a window accepted at its finding ff_time_offset_corrected / _first / _s) and decides adoption: the mean of
    the last `needed` findings once they agree within `agree_s` (s).

    Args:
        needed: `StartupConfig.time_offset_findings`; agree_s: `StartupConfig.time_offset_agree_s`.
        report: the StartupReport the counters go to.
    """

    def __init__(self, needed: int, agree_s: float, report: Any) -> None:
        self.needed = int(needed)
        self.agree_s = float(agree_s)
        self.report = report
        self._recent: list[float] = []

    def record(self, result: Any, may_adopt: bool) -> float | None:
        """Count the finding `result` carries (an InitResult's info["time_offset_s"], a Rejection's
        time_offset_s; none: nothing counted). Returns the offset to adopt now (s, t_imu = t_cam + offset), or
        None: no finding, too few that agree, or not `may_adopt` (then the finding is only counted)."""
        accepted = isinstance(result, InitResult)
        found = result.info.get("time_offset_s") if accepted else getattr(result, "time_offset_s", None)
        if found is None:
            return None
        rep = self.report
        detail = str(result.info.get("time_offset_detail", "") if accepted else getattr(result, "detail", ""))
        rep.time_offset_findings += 1
        rep.time_offset_first = rep.time_offset_first or detail
        if accepted:
            rep.ff_time_offset_corrected += 1
            rep.ff_time_offset_first = rep.ff_time_offset_first or detail
            rep.ff_time_offset_s = float(found)
        self._recent = (self._recent + [float(found)])[-self.needed:]
        agree = max(self._recent) - min(self._recent) <= self.agree_s
        if not (may_adopt and len(self._recent) == self.needed and agree):
            return None
        adopted = float(np.mean(self._recent))
        self._recent = []
        return adopted
