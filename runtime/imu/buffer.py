"""A growable array buffer of IMU samples (time, gyro, accel), oldest first.

The filter appends one sample at a time and, once per camera frame, reads the samples around the propagation
interval and drops the ones it no longer needs. Kept in preallocated arrays, those reads are views (no list of
3-vectors converted per frame); dropping advances a start index and the live part moves to the front only when
the arrays are full.
"""
from __future__ import annotations

import numpy as np


class ImuBuffer:
    """IMU samples t_ns (int64, strictly increasing: the caller checks), gyro w (rad/s) and accel a (m/s^2),
    body frame."""

    def __init__(self, capacity: int = 1024) -> None:
        cap = max(int(capacity), 8)
        self._t = np.empty(cap, np.int64)
        self._w = np.empty((cap, 3))
        self._a = np.empty((cap, 3))
        self._start = 0
        self._end = 0

    def __len__(self) -> int:
        return self._end - self._start

    @property
    def t_ns(self) -> np.ndarray:
        """(N,) sample times, ns (a view: valid until the next append or drop)."""
        return self._t[self._start:self._end]

    @property
    def gyro(self) -> np.ndarray:
        """(N, 3) angular rates, rad/s (a view)."""
        return self._w[self._start:self._end]

    @property
    def accel(self) -> np.ndarray:
        """(N, 3) specific forces, m/s^2 (a view)."""
        return self._a[self._start:self._end]

    @property
    def first_ns(self) -> int | None:
        return int(self._t[self._start]) if self._end > self._start else None

    @property
    def last_ns(self) -> int | None:
        return int(self._t[self._end - 1]) if self._end > self._start else None

    def append(self, t_ns: int, w: np.ndarray, a: np.ndarray) -> None:
        """Add one sample after the newest."""
        if self._end == self._t.shape[0]:
            self._make_room()
        e = self._end
        self._t[e] = t_ns
        self._w[e] = w
        self._a[e] = a
        self._end = e + 1

    def drop_first(self, n: int) -> None:
        """Forget the n oldest samples (all of them when n >= len)."""
        self._start = min(self._start + max(int(n), 0), self._end)
        if self._start == self._end:
            self._start = self._end = 0

    def drop_before(self, t_ns: int) -> None:
        """Forget the samples older than t_ns."""
        self.drop_first(int(np.searchsorted(self.t_ns, t_ns, side="left")))

    def clear(self) -> None:
        self._start = self._end = 0

    def _make_room(self) -> None:
        n = len(self)
        cap = self._t.shape[0]
        if n > cap // 2:                      # mostly live: grow
            cap *= 2
            t, w, a = np.empty(cap, np.int64), np.empty((cap, 3)), np.empty((cap, 3))
        else:                                 # mostly dropped: move the live part to the front
            t, w, a = self._t, self._w, self._a
        t[:n] = self._t[self._start:self._end]
        w[:n] = self._w[self._start:self._end]
        a[:n] = self._a[self._start:self._end]
        self._t, self._w, self._a = t, w, a
        self._start, self._end = 0, n
