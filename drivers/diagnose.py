"""Why an input stream is unusable or in the wrong units, in words that name the fix.

A replay that reads nothing usable must stop with the reason, not run to "0 poses, exit 0". These
checks look at a stamped CSV file whose rows were all rejected (separator, column count, stamp
format, all non-finite), at stamps whose rate is only plausible in another unit (s, ms, µs instead
of ns), and at accelerometer values in g instead of m/s^2.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from drivers.base import StreamCounts
from runtime.errors import DataError

G_STANDARD = 9.80665
"""Standard gravity, m/s^2: the factor from g to m/s^2."""

RATE_RANGE_HZ = {"IMU": (10.0, 10_000.0), "camera": (0.2, 1_000.0)}
"""Sensor rates DAVIO accepts as plausible, per stream kind (Hz)."""

_UNITS = (("microseconds", 1e3, "multiply the stamps by 1000"),
          ("milliseconds", 1e6, "multiply the stamps by 1,000,000"),
          ("seconds", 1e9, "multiply the stamps by 1e9 and write them as integers"))


def _data_lines(path: Path, limit: int = 50) -> list[str]:
    """Up to `limit` non-empty, non-comment lines of a text file (header included)."""
    out: list[str] = []
    try:
        with path.open("r", encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                s = line.strip()
                if s and not s.startswith("#"):
                    out.append(s)
                    if len(out) >= limit:
                        break
    except OSError:
        pass
    return out


def explain_unreadable(path: str | Path, n_values: int, columns: str, counts: StreamCounts) -> str:
    """Why no row of the stamped CSV `path` (stamp + `n_values` columns named `columns`) was kept."""
    path = Path(path)
    lines = _data_lines(path)
    if counts.lines == 0 or not lines:
        return "holds no data rows"
    expected = n_values + 1
    sample = lines[len(lines) // 2]
    fields = [f.strip() for f in sample.split(",")]
    if ";" in sample and len(sample.split(";")) >= expected and len(fields) != expected:
        return ("fields are separated by ';'; EuRoC/ASL CSV files are comma-separated "
                f"({columns}): replace ';' by ','")
    if "," not in sample and len(sample.split()) >= expected:
        return f"fields are separated by spaces or tabs; EuRoC/ASL CSV files are comma-separated ({columns})"
    if counts.truncated_lines + counts.malformed_lines >= counts.lines and len(fields) != expected:
        what = "extra column(s), e.g. a temperature column" if len(fields) > expected else "missing column(s)"
        return (f"rows have {len(fields)} fields where {expected} are expected ({columns}): {what}; "
                "write the expected columns only")
    stamp = fields[0]
    try:
        value = float(stamp)
    except ValueError:
        value = math.nan
    if not (stamp.isascii() and stamp.isdigit()) and math.isfinite(value):
        if value < 1e11:
            return (f"stamps look like seconds ({stamp!r}); DAVIO reads integer nanoseconds: "
                    "multiply by 1e9 and write them without a decimal point")
        return (f"stamps are written as floating-point numbers ({stamp!r}), which cannot hold nanoseconds "
                "exactly; write integer nanoseconds")
    if counts.dropped_nonfinite and counts.dropped_nonfinite + counts.malformed_lines >= counts.lines:
        return "every row holds NaN or Inf values"
    return (f"no row could be read ({counts.truncated_lines} truncated, {counts.malformed_lines} malformed, "
            f"{counts.dropped_nonfinite} non-finite of {counts.lines}); expected {columns}")


def check_distinct_stamps(t_ns: np.ndarray, what: str, path: str | Path) -> None:
    """Raise DataError when one stamp is shared by at least half of ten or more messages: the publisher does
    not stamp them (a header stamp left 0, or set once), which no reordering can repair. (A topic recorded
    twice repeats every stamp once: the time-order repair drops those as duplicates.)"""
    n = int(t_ns.shape[0])
    if n < 10:
        return
    stamps, counts = np.unique(t_ns, return_counts=True)
    k = int(np.argmax(counts))
    if counts[k] * 2 < n:
        return
    raise DataError(f"{what}: {int(counts[k])} of {n} messages share the header stamp {int(stamps[k])} "
                    f"({len(stamps)} distinct stamps): the publisher does not stamp its messages; fix its "
                    "header.stamp (the driver's time source), DAVIO never uses the record time", path)


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


def accel_looks_like_g(accel: np.ndarray) -> float | None:
    """The median accelerometer norm when it says the values are in g (0.5-2), else None.

    A robot's accelerometer measures gravity plus motion: in m/s^2 its median norm is about 9.8.
    """
    if accel.shape[0] < 10:
        return None
    med = float(np.median(np.linalg.norm(accel, axis=1)))
    return med if 0.5 <= med <= 2.0 else None
