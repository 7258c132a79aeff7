"""Why an input stream is unusable, in words that name the fix.

A replay that reads nothing usable must stop with the reason, not run to "0 poses, exit 0". These
checks look at a stamped CSV file whose rows were all rejected (separator, column count, stamp
format, all non-finite) and at messages that share one header stamp. The unit checks (stamps in s, ms
or µs instead of ns, an accelerometer in g) are in `runtime.units`, which the Session API uses too.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from drivers.base import StreamCounts
from runtime.errors import DataError


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
