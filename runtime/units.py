"""Unit checks of sensor streams: stamps in nanoseconds (not s, ms or us) and an accelerometer in m/s^2 (not
g). The file drivers (EuRoC, ROS bags) and the Session API (`add_imu`, `add_image`) use them."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from runtime.errors import DataError

G_STANDARD = 9.80665
"""Standard gravity, m/s^2: the factor from g to m/s^2."""

RATE_RANGE_HZ = {"IMU": (10.0, 10_000.0), "camera": (0.2, 1_000.0)}
"""Sensor rates DAVIO accepts as plausible, per stream kind (Hz)."""

_UNITS = (("microseconds", 1e3, "multiply the stamps by 1000"),
          ("milliseconds", 1e6, "multiply the stamps by 1,000,000"),
          ("seconds", 1e9, "multiply the stamps by 1e9 and write them as integers"))


def check_stamp_units(t_ns: np.ndarray, kind: str, path: str | Path) -> None:
    """Raise DataError when the stamps' median rate is implausible in ns but plausible in another unit.

    `kind` is "IMU" or "camera" (RATE_RANGE_HZ). Fewer than 3 distinct stamps are not judged.
    """
    lo, hi = RATE_RANGE_HZ[kind]
    if t_ns.shape[0] < 3:
        return
    step = float(np.median(np.diff(t_ns)))
    if step <= 0:
        return
    rate = 1e9 / step
    if lo <= rate <= hi:
        return
    for unit, factor, fix in _UNITS:
        if lo <= 1e9 / (step * factor) <= hi:
            raise DataError(f"{kind} stamps look like {unit}, not nanoseconds: the median step {step:g} "
                            f"would mean {rate:.3g} Hz in ns but {1e9 / (step * factor):.4g} Hz in "
                            f"{unit}; {fix}", path)
    raise DataError(f"implausible {kind} rate {rate:.3g} Hz from the stamps' median step {step:g} ns "
                    f"(expected {lo:g}-{hi:g} Hz); stamps must be integer nanoseconds", path)


def repeated_stamps_cause(t_ns: np.ndarray) -> str:
    """Why IMU stamps (ns, in order received) repeat: samples a driver stamps once per batch (runs of one
    stamp, the runs at a plausible rate in ns), or stamps in coarser units; what to do."""
    t = np.asarray(t_ns, np.int64)
    starts = np.flatnonzero(np.r_[True, np.diff(t) != 0])
    runs = np.diff(np.r_[starts, len(t)])
    steps = np.diff(t[starts])
    hi = RATE_RANGE_HZ["IMU"][1]
    step = float(np.median(steps)) if len(steps) >= 2 and np.all(steps > 0) else 0.0
    coarse = step in (1e9, 1e6)     # one step of exactly a second or a millisecond: truncated stamps
    if step > 0 and not coarse:
        batch_hz = 1e9 / step
        if 5.0 <= batch_hz <= hi and float(np.median(runs)) > 1:
            return (f"the samples come in batches of about {np.median(runs):g} sharing one stamp, "
                    f"{batch_hz:.3g} batches per second: stamp each sample (spread a batch over its period, "
                    "the last sample at the batch's stamp); stamps must be integer nanoseconds, one per "
                    "sample")
    return "stamps must be integer nanoseconds, one per sample (whole seconds or milliseconds?)"


def accel_looks_like_g(accel: np.ndarray) -> float | None:
    """The median accelerometer norm when it says the values are in g (0.5-2), else None.

    A robot's accelerometer measures gravity plus motion: in m/s^2 its median norm is about 9.8.
    """
    if accel.shape[0] < 10:
        return None
    med = float(np.median(np.linalg.norm(accel, axis=1)))
    return med if 0.5 <= med <= 2.0 else None
