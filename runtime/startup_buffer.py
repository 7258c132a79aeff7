"""The start-up's replay buffer: the last seconds of measurements (IMU samples, feature-track sets) with
sequence numbers, and the choice of buffered frames nearest to ideal times."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class _Entry:
    seq: int
    kind: str  # "imu" | "tracks"
    t_ns: int  # sensor time (IMU clock for imu, camera clock for tracks)
    payload: Any


class MeasurementBuffer:
    """The last `buffer_s` seconds of measurements, with monotonically increasing sequence numbers."""

    def __init__(self, buffer_s: float) -> None:
        self.horizon_ns = int(buffer_s * 1e9)
        self.entries: deque[_Entry] = deque()
        self.next_seq = 0

    def append(self, kind: str, t_ns: int, payload: Any) -> int:
        e = _Entry(self.next_seq, kind, int(t_ns), payload)
        self.entries.append(e)
        self.next_seq += 1
        return e.seq

    @property
    def first_seq(self) -> int:
        return self.entries[0].seq if self.entries else self.next_seq

    def trim(self, newest_ns: int, keep_from_seq: int | None = None) -> None:
        """Drop entries older than the horizon, but never one at or after keep_from_seq."""
        while self.entries and self.entries[0].t_ns < newest_ns - self.horizon_ns:
            if keep_from_seq is not None and self.entries[0].seq >= keep_from_seq:
                break
            self.entries.popleft()

    def get(self, seq: int) -> _Entry:
        return self.entries[seq - self.first_seq]

    def tracks_at(self, stamps: list[int]) -> list[tuple[int, np.ndarray, np.ndarray]] | None:
        """The buffered feature-track sets (t_cam_ns, ids, uv) at each camera stamp, or None if one is
        not (or no longer) buffered."""
        by_t = {e.t_ns: e.payload for e in self.entries if e.kind == "tracks"}
        out = [by_t.get(int(t)) for t in stamps]
        return None if any(o is None for o in out) else out

    def imu_arrays(self, t0_ns: int, t1_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IMU samples with t0 <= t <= t1 (IMU clock) as arrays (t_ns, gyro, accel)."""
        s = [e.payload for e in self.entries if e.kind == "imu" and t0_ns <= e.t_ns <= t1_ns]
        if not s:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
        return (np.array([x.t_ns for x in s], np.int64), np.array([x.gyro for x in s], float),
                np.array([x.accel for x in s], float))


def nearest_stamps(stamps_ns: np.ndarray, ideal_ns: list[int], tol_s: float) -> list[int] | None:
    """Index of the stamp nearest each ideal time (ns), or None when one is farther than tol_s or two
    ideal times pick the same stamp."""
    out = []
    for ideal in ideal_ns:
        i = int(np.argmin(np.abs(stamps_ns - ideal)))
        if abs(int(stamps_ns[i]) - ideal) > tol_s * 1e9:
            return None
        out.append(i)
    return out if len(set(out)) == len(out) else None
