"""The newest frames a live camera keeps for its one consumer, and the rate they arrived at.

Shared by the live camera drivers (`drivers.uvc`, `drivers.oak`): each holds `keep_frames`, the deque
`_buf`, the counters `frames` (kept) and `dropped_old` (pushed out by newer ones), the first and last kept
stamps `_first_t`, `_last_t` (ns, the driver's clock) and the condition `_cond` its reader notifies.
"""
from __future__ import annotations

from typing import Any


class KeptFrames:
    """Mixin: keep the newest `keep_frames` frames, count the older ones dropped, measure the rate."""

    keep_frames: int
    frames: int
    dropped_old: int
    _buf: Any
    _cond: Any
    _first_t: int | None
    _last_t: int | None

    def _keep_newest(self, frame: Any) -> None:
        """Append `frame` (its stamp `t_ns`), dropping the oldest beyond `keep_frames`.

        The caller holds `_cond`; its waiters are notified."""
        if len(self._buf) >= self.keep_frames:
            self._buf.popleft()
            self.dropped_old += 1
        self._buf.append(frame)
        self.frames += 1
        if self._first_t is None:
            self._first_t = frame.t_ns
        self._last_t = frame.t_ns
        self._cond.notify_all()

    def fps_measured(self) -> float | None:
        """Rate of the kept frames from their first and last stamps, Hz (None before two frames)."""
        if self._first_t is None or self._last_t is None or self.frames < 2 or self._last_t <= self._first_t:
            return None
        return (self.frames - 1) * 1e9 / (self._last_t - self._first_t)
