"""Pairing separate accelerometer and gyroscope report streams into IMU samples at the gyroscope stamps.

Devices such as the OAK's BNO08x / BMI270 deliver the two sensors as separate reports with their own
stamps (int64 ns of the device clock). DAVIO's `ImuSample` holds both at one stamp, so each gyroscope
report takes the accelerometer at its stamp: exact when a report has the same stamp, else linearly
interpolated between the two accelerometer reports around it. Every report that cannot be used is
counted (`counts()`), never dropped silently.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Sequence

import numpy as np

from runtime.events import ImuSample


class ImuPairer:
    """Pairs accelerometer and gyroscope reports into samples at the gyroscope stamps.

    `add_accel(t, xyz)` / `add_gyro(t, xyz)` take one report each (device ns); `pop()` returns the
    samples that can be formed so far: each gyroscope report waits until an accelerometer report at or
    after its stamp exists, then takes the accelerometer at its stamp (exact when equal, else linear
    between the two reports around it). Gyroscope reports older than the first accelerometer report
    are dropped (`unpaired`); so are the oldest of more than `max_pending` waiting ones (an
    accelerometer that stopped). A report whose stamp does not increase is dropped (`repeated`).
    """

    def __init__(self, max_pending: int = 64) -> None:
        self.max_pending = int(max_pending)
        self._acc: deque[tuple[int, np.ndarray]] = deque()
        self._gyr: deque[tuple[int, np.ndarray]] = deque()
        self._last_acc: int | None = None
        self._last_gyr: int | None = None
        self.accel_reports = self.gyro_reports = 0
        self.repeated = self.unpaired = self.paired = self.interpolated = 0

    def add_accel(self, t_ns: int, xyz: Sequence[float]) -> None:
        self.accel_reports += 1
        if self._last_acc is not None and t_ns <= self._last_acc:
            self.repeated += 1
            return
        self._last_acc = t_ns
        self._acc.append((t_ns, np.asarray(xyz, dtype=np.float64)))

    def add_gyro(self, t_ns: int, xyz: Sequence[float]) -> None:
        self.gyro_reports += 1
        if self._last_gyr is not None and t_ns <= self._last_gyr:
            self.repeated += 1
            return
        self._last_gyr = t_ns
        self._gyr.append((t_ns, np.asarray(xyz, dtype=np.float64)))
        while len(self._gyr) > self.max_pending:
            self._gyr.popleft()
            self.unpaired += 1

    def pop(self) -> list[ImuSample]:
        out: list[ImuSample] = []
        acc, gyr = self._acc, self._gyr
        while gyr and acc:
            t, g = gyr[0]
            if t < acc[0][0]:  # before every accelerometer report still held: cannot be paired
                gyr.popleft()
                self.unpaired += 1
                continue
            if acc[-1][0] < t:  # the accelerometer has not reached it yet
                break
            while len(acc) >= 2 and acc[1][0] <= t:
                acc.popleft()
            t0, a0 = acc[0]
            if t0 == t:
                a = a0.copy()
            else:
                t1, a1 = acc[1]
                w = (t - t0) / (t1 - t0)
                a = a0 + w * (a1 - a0)
                self.interpolated += 1
            gyr.popleft()
            self.paired += 1
            out.append(ImuSample(int(t), g, a))
        return out

    def counts(self) -> dict[str, int]:
        return {"accel_reports": self.accel_reports, "gyro_reports": self.gyro_reports,
                "repeated": self.repeated, "unpaired": self.unpaired, "paired": self.paired,
                "interpolated": self.interpolated, "waiting": len(self._gyr)}
