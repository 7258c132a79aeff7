"""Fakes for the start-up handoff and race tests: a filter that records what it is fed and initialises
when told, and a synthetic IMU + frame stream."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np


class RecordingFilter:
    """A stand-in filter that records every measurement and emits one state per frame once
    initialised (a frame is processed when the IMU has reached its time, like the real filter)."""

    def __init__(self, native_init_at_ns: int | None = None) -> None:
        self.fed: list[tuple[str, int]] = []
        self.t_init: int | None = None
        self.native_init_at_ns = native_init_at_ns
        self.init_source: str | None = None
        self.pending: list[int] = []
        self.last_imu = -1

    @property
    def initialized(self) -> bool:
        return self.t_init is not None

    def initialize_from_state(self, t_ns, R_OI, p_OI, v_OI, bg, ba, cov, source="x", time_offset_s=None):
        self.t_init = int(t_ns)
        self.init_source = source
        self.time_offset_s = time_offset_s

    def feed_imu(self, s):
        self.fed.append(("imu", int(s.t_ns)))
        self.last_imu = int(s.t_ns)
        return self._drain()

    def feed_tracks(self, t, ids, uv):
        self.fed.append(("tracks", int(t)))
        if self.t_init is None and self.native_init_at_ns is not None and t >= self.native_init_at_ns:
            self.initialize_from_state(t, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3),
                                       None, "static")
        if self.t_init is not None and t > self.t_init:
            self.pending.append(int(t))
        return self._drain()

    def _drain(self):
        out = []
        while self.pending and self.pending[0] <= self.last_imu:
            t = self.pending.pop(0)
            out.append(SimpleNamespace(t_ns=t, t_cam_ns=t, R_OI=np.eye(3), p_OI=np.zeros(3),
                                       v_OI=np.zeros(3)))
        return out


def stream(seconds: float, imu_hz: int = 200, cam_hz: int = 20):
    """Merged events (IMU first at equal stamps)."""
    ev = []
    for k in range(int(seconds * imu_hz) + 1):
        t = k * (1_000_000_000 // imu_hz)
        ev.append(("imu", t))
    for k in range(int(seconds * cam_hz) + 1):
        ev.append(("cam", k * (1_000_000_000 // cam_hz)))
    ev.sort(key=lambda e: (e[1], e[0] != "imu"))
    return ev
