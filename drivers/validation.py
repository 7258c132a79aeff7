"""Validated reading of stamped CSV files (EuRoC/ASL style) with counted drop policies.

Each data row is `stamp_ns, v1, ..., vk` with an integer nanosecond stamp (parsed as int64, never
as float). Bad rows are either dropped and counted in a `StreamCounts` ("drop" policy) or raise a
`DataError` naming the file and 1-based line ("strict" policy).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.base import IntakeReport, Policy, StreamCounts, check_policy
from runtime.errors import DataError


@dataclass
class StampedRows:
    """Rows of a stamped CSV file that survived validation.

    Attributes:
        t_ns: (N,) int64 stamps, strictly increasing.
        values: (N, k) float64 numeric columns (numeric tables), else (N, 0).
        text: the k text columns per row (text tables such as cam0/data.csv), else [].
        line: (N,) 1-based line numbers in the file.
    """

    t_ns: np.ndarray
    values: np.ndarray
    text: list[list[str]]
    line: np.ndarray


def _parse_stamp(field: str) -> int | None:
    """An integer nanosecond stamp from a decimal digit string, or None when it is not one."""
    if not field.isdigit():  # rejects signs, decimal points, exponents and empty strings
        return None
    return int(field)


def read_stamped_csv(path: str | Path, n_values: int, counts: StreamCounts, policy: Policy = "drop",
                     *, text: bool = False, report: IntakeReport | None = None,
                     monotonic: bool = True,
                     row_check: Callable[[list[float]], str | None] | None = None) -> StampedRows:
    """Read a stamped CSV file, validating every row.

    Args:
        path: the CSV file. Lines starting with '#' are comments; a first non-comment line whose
            first field is not an integer is taken as a text header (noted in `report`).
        n_values: number of columns after the stamp.
        counts: counters of this stream, updated in place.
        policy: "drop" (count and skip bad rows) or "strict" (raise DataError with file and line).
        text: keep the value columns as stripped strings (no numeric parsing or finiteness check).
        report: where notes such as header variations go (optional).
        row_check: extra test of a row's numeric values returning a reason to reject it (counted
            as malformed) or None.
        monotonic: make stamps strictly increasing: "drop" removes the fewest rows that achieve it
            (a longest increasing subsequence; dropped rows repeating the previous row's stamp count
            as duplicates, the others as non-monotonic); "strict" raises at the first stamp not
            after its predecessor.

    Raises:
        DataError: the file cannot be read, or (strict) a row is bad.
    """
    check_policy(policy)
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read file: {exc.strerror or exc}", path) from exc
    try:
        content = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DataError(f"not a UTF-8 text file (byte {exc.start})", path) from exc

    stamps: list[int] = []
    rows: list[list[float]] = []
    texts: list[list[str]] = []
    lines: list[int] = []
    last = -1
    seen_data = False

    def reject(counter: str, lineno: int, why: str) -> None:
        setattr(counts, counter, getattr(counts, counter) + 1)
        if policy == "strict":
            raise DataError(why, path, lineno)

    for lineno, line in enumerate(content.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = [f.strip() for f in stripped.split(",")]
        if not seen_data and _parse_stamp(fields[0]) is None and not fields[0][:1].isdigit():
            if report is not None:
                report.note(f"{path.name}: line {lineno} read as a header without '#': {stripped[:60]!r}")
            seen_data = True
            continue
        seen_data = True
        counts.lines += 1
        if len(fields) < n_values + 1:
            reject("truncated_lines", lineno, f"truncated row: {len(fields)} fields, expected {n_values + 1}")
            continue
        if len(fields) > n_values + 1:
            reject("malformed_lines", lineno, f"{len(fields)} fields, expected {n_values + 1}")
            continue
        t = _parse_stamp(fields[0])
        if t is None or t >= 2**63:
            reject("malformed_lines", lineno, f"stamp {fields[0]!r} is not an integer number of nanoseconds")
            continue
        if text:
            if any(not f for f in fields[1:]):
                reject("truncated_lines", lineno, "empty field")
                continue
            values: list[float] = []
        else:
            try:
                values = [float(f) for f in fields[1:]]
            except ValueError:
                reject("malformed_lines", lineno, f"unparseable number in {stripped[:80]!r}")
                continue
            if not all(math.isfinite(v) for v in values):
                reject("dropped_nonfinite", lineno, "NaN or Inf value")
                continue
            if row_check is not None:
                why = row_check(values)
                if why is not None:
                    reject("malformed_lines", lineno, why)
                    continue
        if monotonic and policy == "strict" and t <= last:
            what = "duplicate stamp" if t == last else "stamp earlier than previous stamp"
            raise DataError(f"{what}: {t} after {last}", path, lineno)
        last = t
        stamps.append(t)
        lines.append(lineno)
        if text:
            texts.append(fields[1:])
        else:
            rows.append(values)

    t_arr = np.array(stamps, dtype=np.int64)
    v_arr = np.array(rows, dtype=np.float64).reshape(len(rows), n_values) if not text \
        else np.zeros((len(stamps), 0))
    line_arr = np.array(lines, dtype=np.int64)
    if monotonic and np.any(np.diff(t_arr) <= 0):
        keep = monotonic_keep_mask(t_arr)
        same_as_previous = np.r_[False, t_arr[1:] == t_arr[:-1]]
        dup = ~keep & same_as_previous
        counts.dropped_duplicate += int(dup.sum())
        counts.dropped_nonmonotonic += int((~keep & ~dup).sum())
        t_arr, v_arr, line_arr = t_arr[keep], v_arr[keep], line_arr[keep]
        if text:
            texts = [r for r, k in zip(texts, keep, strict=True) if k]
    counts.parsed += int(t_arr.shape[0])
    return StampedRows(t_arr, v_arr, texts, line_arr)


def monotonic_keep_mask(t_ns: np.ndarray) -> np.ndarray:
    """Mask of a longest strictly increasing subsequence of `t_ns`, preferring earlier rows.

    Dropping the complement removes the fewest rows that make the stamps strictly increasing, so a
    single stamp that jumps far ahead costs one row, not every row after it. Among equally long
    choices the earlier rows are kept (a late, out-of-order row is the one dropped).
    """
    import bisect

    # patience sorting on the reversed, negated stamps: a longest decreasing run read backwards;
    # replacing on ties makes each run end at the earliest original row
    s = [-int(x) for x in t_ns[::-1]]
    tails: list[int] = []
    tail_idx: list[int] = []
    prev = [-1] * len(s)
    for i, x in enumerate(s):
        k = bisect.bisect_left(tails, x)
        if k == len(tails):
            tails.append(x)
            tail_idx.append(i)
        else:
            tails[k] = x
            tail_idx[k] = i
        prev[i] = tail_idx[k - 1] if k > 0 else -1
    keep_rev = np.zeros(len(s), dtype=bool)
    i = tail_idx[-1] if tail_idx else -1
    while i >= 0:
        keep_rev[i] = True
        i = prev[i]
    return keep_rev[::-1].copy()


def count_gaps(t_ns: np.ndarray, counts: StreamCounts, factor: float = 1.5) -> None:
    """Count intervals longer than `factor` x the median period (upstream drops) into `counts`."""
    if t_ns.shape[0] < 3:
        return
    dt = np.diff(t_ns)
    median = int(np.median(dt))
    counts.median_period_ns = median
    if median <= 0:
        return
    big = dt > factor * median
    counts.gaps = int(big.sum())
    counts.missing_estimated = int(np.maximum(np.rint(dt[big] / median) - 1, 0).sum())
