"""Validated reading of stamped CSV files (EuRoC/ASL style) with counted drop policies.

Each data row is `stamp_ns, v1, ..., vk` with an integer nanosecond stamp (parsed as int64, never
as float). Bad rows are either dropped and counted in a `StreamCounts` ("drop" policy) or raise a
`DataError` naming the file and 1-based line ("strict" policy).
"""
from __future__ import annotations

import math
import re
from collections import deque
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
    if not (field.isascii() and field.isdigit()):  # rejects signs, points, exponents, "" and "¹"
        return None
    return int(field)


_EXPONENT = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)[eE]([-+]?)(\d*)$")


def _exponent_cut(last: str, before: list[str]) -> bool:
    """Whether a last value is certainly cut short: the rows before write it in exponent form (at least
    90 % of them, e.g. numpy.savetxt's '%.18e'), and here the exponent is missing or has fewer digits than
    they use ('1.249e-0' for '1.249e-01'). A value written in plain decimals cannot be told from a shorter
    one ('-3' for '-3.2035'); such a line is kept with a note."""
    if len(before) < 10:
        return False
    digits = [len(m.group(3)) for f in before if (m := _EXPONENT.match(f))]
    if len(digits) < 0.9 * len(before):
        return False
    m = _EXPONENT.match(last)
    return m is None or len(m.group(3)) < min(digits)


def is_float(text: str) -> bool:
    """Whether `text` reads as a number (nan, inf and 1e3 included): a corrupt stamp, not a header word."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_stamped_csv(path: str | Path, n_values: int, counts: StreamCounts, policy: Policy = "drop",
                     *, text: bool = False, report: IntakeReport | None = None,
                     monotonic: bool = True,
                     row_check: Callable[[list[float]], str | None] | None = None) -> StampedRows:
    """Read a stamped CSV file, validating every row.

    Args:
        path: the CSV file. Lines starting with '#' are comments; a first non-comment line whose
            fields are all words (none reads as a number) is taken as a text header (noted in `report`).
            A last line without a line end is kept with a note unless its last value certainly lost
            exponent digits (`_exponent_cut`), which counts it as truncated.
        n_values: number of columns after the stamp.
        counts: counters of this stream, updated in place.
        policy: "drop" (count and skip bad rows) or "strict" (raise DataError with file and line).
        text: keep the value columns as stripped strings (no numeric parsing or finiteness check).
        report: where notes such as header variations go (optional).
        row_check: extra test of a row's numeric values returning a reason to reject it (counted
            as malformed) or None.
        monotonic: make stamps strictly increasing: "drop" sorts the rows by stamp (rows moved are
            counted as reordered), drops rows repeating an earlier stamp (duplicates) and moved rows
            whose stamp is far from every other (corrupt stamps, counted as non-monotonic), see
            `time_order_repair`; "strict" raises at the first stamp not after its predecessor.

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

    all_lines = content.splitlines()
    recent: deque[list[str]] = deque(maxlen=200)   # the last rows' fields, for the cut-off test
    # a file cut off while written ends inside its last row, where a number may still parse (-3.20 -> -3)
    unterminated = len(all_lines) if content and not content.endswith(("\n", "\r")) else 0
    for lineno, line in enumerate(all_lines, start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            continue
        fields = [f.strip() for f in stripped.split(",")]
        if not seen_data and not any(is_float(f) or is_float(f.rsplit(".", 1)[0]) for f in fields):
            if report is not None:
                report.note(f"{path.name}: line {lineno} read as a header without '#': {stripped[:60]!r}")
            seen_data = True
            continue
        seen_data = True
        counts.lines += 1
        if lineno == unterminated:
            if _exponent_cut(fields[-1], [t[-1] for t in recent]):
                if report is not None:
                    report.note(f"{path.name}: the last line has no line end and its last value lost "
                                "exponent digits (the file was cut off while written): dropped")
                reject("truncated_lines", lineno, "the last line has no line end and its last value lost "
                                                  "exponent digits (cut off while written)")
                continue
            if report is not None:
                report.note(f"{path.name}: the last line has no line end: kept; if the file was cut off "
                            "while written, its last value may be short")
        recent.append(fields)
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
                # float() reads '1_0' as 10 and '\u0661' (Arabic-Indic one) as 1: neither is a CSV number
                if "_" in stripped or not stripped.isascii():
                    raise ValueError
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
        order, kept, dup, isolated = time_order_repair(t_arr)
        at = clock_reset(t_arr, v_arr)
        if at is not None:
            raise DataError(f"stamps jump back by {(int(t_arr[at - 1]) - int(t_arr[at])) * 1e-9:.3f} s here "
                            "and run on from there (a clock reset, or two files spliced?): the rows cannot "
                            "be sorted into one time order; split the file there or correct the stamps",
                            path, int(line_arr[at]))
        counts.dropped_duplicate += int(dup.sum())
        counts.dropped_nonmonotonic += int(isolated.sum())
        counts.reordered += int(kept.sum())
        keep = ~(dup | isolated)
        order = order[keep[order]]
        t_arr, v_arr, line_arr = t_arr[order], v_arr[order], line_arr[order]
        if text:
            texts = [texts[i] for i in order]
    drop = isolated_ends(t_arr) if monotonic else None
    if drop is not None and drop.any():
        k = int(np.flatnonzero(drop)[0])
        gap_s = float(np.min(np.abs(t_arr[np.flatnonzero(~drop)] - t_arr[k]))) * 1e-9
        why = f"stamp {int(t_arr[k])} lies {gap_s:.3g} s from every other row (a corrupt stamp?)"
        if policy == "strict":
            raise DataError(why, path, int(line_arr[k]))
        if report is not None:
            report.note(f"{path.parent.name}/{path.name}: line {int(line_arr[k])}: {why}; dropped"
                        + (" (and the row at the other end too)" if drop.sum() > 1 else ""))
        counts.dropped_nonmonotonic += int(drop.sum())
        t_arr, v_arr, line_arr = t_arr[~drop], v_arr[~drop], line_arr[~drop]
        if text:
            texts = [t for t, d in zip(texts, drop, strict=True) if not d]
    counts.parsed += int(t_arr.shape[0])
    return StampedRows(t_arr, v_arr, texts, line_arr)


def isolated_ends(t_ns: np.ndarray) -> np.ndarray:
    """(N,) bool: the first and last row of a sorted stream when its stamp lies more than ISOLATED_GAP_S
    and 100 median periods from the next row in (a corrupt stamp that sorts to an end: 0, or one flipped
    high bit); one row at each end at most, and none in a stream of fewer than 10 rows."""
    out = np.zeros(t_ns.shape[0], bool)
    if t_ns.shape[0] < 10:
        return out
    step = np.diff(t_ns)
    limit = max(ISOLATED_GAP_S * 1e9, 100.0 * float(np.median(step)))
    out[0] = step[0] > limit
    out[-1] = step[-1] > limit
    return out


ISOLATED_GAP_S = 1.0
"""An out-of-order row whose stamp lies this far (and 100 median periods) from every other row is
taken as a corrupt stamp and dropped rather than sorted into place."""


def time_order_repair(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """How to put a stream with stamps out of order into strictly increasing time order.

    Rows are sorted by stamp (stable: at equal stamps the first row in the file is kept and the later
    ones are duplicates). The rows that had to move are the complement of a longest increasing
    subsequence (the fewest moves); a moved row whose stamp lies far from every other stamp (a
    corrupt stamp, e.g. one flipped bit) is dropped instead of sorted in.

    Returns:
        order: (N,) stable argsort of `t_ns`.
        moved_kept: (N,) bool, rows sorted into place (counted as reordered).
        duplicate: (N,) bool, rows repeating an earlier row's stamp.
        isolated: (N,) bool, moved rows with a corrupt-looking stamp.
    """
    n = t_ns.shape[0]
    order = np.argsort(t_ns, kind="stable")
    ts = t_ns[order]
    dup_sorted = np.concatenate([np.zeros(min(n, 1), bool), ts[1:] == ts[:-1]])
    duplicate = np.zeros(n, bool)
    duplicate[order[dup_sorted]] = True
    moved = ~monotonic_keep_mask(t_ns) & ~duplicate
    # isolation: distance to the nearest other distinct stamp, in sorted order
    uniq = ts[~dup_sorted]
    isolated = np.zeros(n, bool)
    if uniq.shape[0] >= 3 and moved.any():
        period = float(np.median(np.diff(uniq)))
        limit = max(ISOLATED_GAP_S * 1e9, 100.0 * period)
        k = np.searchsorted(uniq, t_ns)
        left = np.where(k > 0, t_ns - uniq[np.maximum(k - 1, 0)], np.inf)
        right = np.where(k + 1 < uniq.shape[0], uniq[np.minimum(k + 1, uniq.shape[0] - 1)] - t_ns, np.inf)
        isolated = moved & (np.minimum(left, right) > limit)
    return order, moved & ~isolated, duplicate, isolated


def _repeated_block(t_ns: np.ndarray, values: np.ndarray | None, lo: int, hi: int) -> bool:
    """Whether rows lo..hi-1 repeat earlier rows: the same stamps, and the same values when given."""
    earlier_t = t_ns[:lo]
    order = np.argsort(earlier_t, kind="stable")
    k = np.searchsorted(earlier_t[order], t_ns[lo:hi])
    if np.any(k >= order.shape[0]):
        return False
    match = order[k]
    if not np.array_equal(earlier_t[match], t_ns[lo:hi]):
        return False
    return values is None or values.shape[1] == 0 or np.array_equal(values[match], values[lo:hi])


RESET_RUN = 10
"""Rows after a jump back that must follow on at the stream's rate for the jump to be a clock reset."""


def clock_reset(t_ns: np.ndarray, values: np.ndarray | None = None) -> int | None:
    """Index of the first row after a clock reset, or None.

    A reset is a step back by more than the isolation limit (ISOLATED_GAP_S and 100 median periods) from
    a row that itself continues its predecessor at the stream's rate, after which at least RESET_RUN rows
    follow on at that rate: two clocks, whether the second one's span lies apart from the first's or
    inside it. Not one: a single corrupt stamp, far behind or far ahead (its neighbours do not follow on
    from it; dropped as isolated by `time_order_repair`), a block written twice (its rows are duplicates)
    and a chunk written late into the gap it belongs to (sorted into place)."""
    n = t_ns.shape[0]
    if n < RESET_RUN + 2:
        return None
    step = np.diff(t_ns)
    forward = step[step > 0]
    if forward.size == 0:
        return None
    limit = max(ISOLATED_GAP_S * 1e9, 100.0 * float(np.median(forward)))
    on_rate = (step > 0) & (step <= limit)
    for i in np.nonzero(step < -limit)[0]:          # the step from row i to row i + 1
        before_ok = i == 0 or on_rate[i - 1]
        if not (before_ok and i + 1 + RESET_RUN <= step.shape[0] and on_rate[i + 1:i + 1 + RESET_RUN].all()):
            continue
        # the rows after the jump that run on at the stream's rate behind the stamp before it: i+1 .. end
        end = i + 1
        while end < step.shape[0] and on_rate[end] and t_ns[end + 1] <= t_ns[i]:
            end += 1
        if end - i < RESET_RUN:
            continue
        run = t_ns[i + 1:end + 1]
        rest = np.concatenate([t_ns[:i + 1], t_ns[end + 1:]])
        if _repeated_block(t_ns, values, i + 1, end + 1):   # a block written twice: duplicates
            continue
        inside = (rest > run[0]) & (rest < run[-1])
        if rest.min() < run[0] and run[-1] < rest.max() and not inside.any():
            continue                                 # a chunk written late into its own gap: sortable
        return int(i) + 1
    return None


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
