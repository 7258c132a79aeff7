"""Stamped-CSV validation helpers: the fewest-rows monotonic repair against brute force."""
from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.base import StreamCounts
from drivers.validation import count_gaps, monotonic_keep_mask, read_stamped_csv, time_order_repair


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 6), min_size=0, max_size=8))
def test_keep_mask_is_a_longest_strictly_increasing_subsequence(stamps: list[int]) -> None:
    t = np.array(stamps, dtype=np.int64)
    keep = monotonic_keep_mask(t)
    assert np.all(np.diff(t[keep]) > 0)
    n = len(stamps)
    best = max((len(c) for r in range(n + 1) for c in itertools.combinations(range(n), r)
                if all(t[b] > t[a] for a, b in itertools.pairwise(c))), default=0)
    assert int(keep.sum()) == best


def test_counts_add_up_on_mixed_defects(tmp_path: Path) -> None:
    f = tmp_path / "x.csv"
    f.write_text("# t,a\n10,1\n20,2\n20,3\n15,4\n30,nan\n40,x\n50\n60,6,7\n70,7\n")
    c = StreamCounts()
    rows = read_stamped_csv(f, 1, c)
    np.testing.assert_array_equal(rows.t_ns, [10, 15, 20, 70])   # 15 sorted into place
    np.testing.assert_array_equal(rows.line, [2, 5, 3, 10])
    assert (c.dropped_duplicate, c.dropped_nonmonotonic, c.reordered, c.dropped_nonfinite, c.malformed_lines,
            c.truncated_lines) == (1, 0, 1, 1, 2, 1)
    assert c.lines == 9 and c.rows_accounted()


def test_gap_counting() -> None:
    c = StreamCounts()
    t = np.array([0, 10, 20, 30, 60, 70, 80, 95], dtype=np.int64)
    count_gaps(t, c)
    assert c.median_period_ns == 10 and c.gaps == 1 and c.missing_estimated == 2


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 40), min_size=0, max_size=30))
def test_time_order_repair_sorts_keeps_every_distinct_stamp_and_counts_each_row(stamps: list[int]) -> None:
    """Small stamps (ns) are never isolated (1 s limit): every distinct stamp survives once, sorted."""
    t = np.array(stamps, dtype=np.int64)
    order, moved, dup, isolated = time_order_repair(t)
    assert not isolated.any()
    kept = order[~dup[order]]
    np.testing.assert_array_equal(t[kept], np.unique(t))
    assert int(dup.sum()) == len(stamps) - len(set(stamps))
    # the rows moved are as few as possible: the complement of a longest increasing run
    assert int(moved.sum()) == int((~monotonic_keep_mask(t) & ~dup).sum())
    for i in np.flatnonzero(dup):   # the first row of an equal-stamp group is the one kept
        assert any(t[j] == t[i] for j in range(i))


def test_reversed_and_shuffled_files_are_sorted_not_cut(tmp_path: Path) -> None:
    period = 5_000_000
    t = [1_000_000_000 + k * period for k in range(50)]
    rng = np.random.default_rng(3)
    for name, rows in (("reversed", t[::-1]), ("shuffled", list(rng.permutation(t)))):
        f = tmp_path / f"{name}.csv"
        f.write_text("".join(f"{x},{x % 7}\n" for x in rows))
        c = StreamCounts()
        out = read_stamped_csv(f, 1, c)
        np.testing.assert_array_equal(out.t_ns, t)
        np.testing.assert_array_equal(out.values[:, 0], [x % 7 for x in t])   # values travel with stamps
        assert c.parsed == 50 and c.dropped == 0 and c.reordered == 50 - int(monotonic_keep_mask(
            np.array(rows, np.int64)).sum())


def test_a_far_corrupt_stamp_is_dropped_not_sorted_in(tmp_path: Path) -> None:
    t = [10**12 + k * 5_000_000 for k in range(40)]
    rows = list(t)
    rows[7] = t[7] + 3 * 10**9 * 1000   # ~3000 s ahead: a corrupt stamp
    rows[20], rows[21] = rows[21], rows[20]   # a swapped pair: sorted back
    f = tmp_path / "x.csv"
    f.write_text("".join(f"{x},1\n" for x in rows))
    c = StreamCounts()
    out = read_stamped_csv(f, 1, c)
    np.testing.assert_array_equal(out.t_ns, [x for i, x in enumerate(t) if i != 7])
    assert (c.dropped_nonmonotonic, c.reordered, c.parsed) == (1, 1, 39)


def test_a_number_with_digit_groups_is_malformed_not_read_as_another_number(tmp_path: Path) -> None:
    """Python's float() reads '1_0' as 10: an IMU row so written would have been a 10 rad/s reading."""
    f = tmp_path / "imu.csv"
    f.write_text("# t,wx,wy\n10,0.1,0.2\n20,1_0,0.2\n30,0.1,2_5e-1\n40,0.3,0.4\n")
    c = StreamCounts()
    rows = read_stamped_csv(f, 2, c)
    np.testing.assert_array_equal(rows.t_ns, [10, 40])
    np.testing.assert_array_equal(rows.values, [[0.1, 0.2], [0.3, 0.4]])
    assert c.malformed_lines == 2 and c.rows_accounted()


def test_a_number_in_other_digits_is_malformed_not_read(tmp_path: Path) -> None:
    """float() reads Arabic-Indic or full-width digits ('\u0661' is 1): no CSV writer means them."""
    f = tmp_path / "imu.csv"
    f.write_text("# t,wx,wy\n10,0.1,0.2\n20,\u0661,0.2\n30,0.1,\uff15\n40,0.3,0.4\n", encoding="utf-8")
    assert float("\u0661") == 1.0 and float("\uff15") == 5.0           # the premise
    c = StreamCounts()
    rows = read_stamped_csv(f, 2, c)
    np.testing.assert_array_equal(rows.t_ns, [10, 40])
    assert c.malformed_lines == 2 and c.rows_accounted()


def test_a_corrupt_stamp_sorting_to_an_end_is_dropped_and_said(tmp_path: Path) -> None:
    """A first stamp of 0 (or one with a flipped high bit at the end) is in time order, so no reordering
    catches it: it made the run's clock start 1e9 s early, and a 'gap' of 31 years."""
    from drivers.base import IntakeReport
    from runtime.errors import DataError

    t = [10**18 + 5_000_000 * k for k in range(40)]
    t[0], t[-1] = 0, t[-1] + 2**60
    f = tmp_path / "imu0" / "data.csv"
    f.parent.mkdir()
    f.write_text("# t,wx\n" + "".join(f"{s},{k}\n" for k, s in enumerate(t)))
    c, report = StreamCounts(), IntakeReport("test", str(f))
    rows = read_stamped_csv(f, 1, c, report=report)
    np.testing.assert_array_equal(rows.t_ns, t[1:-1])
    np.testing.assert_array_equal(rows.values[:, 0], np.arange(1, 39))
    assert c.dropped_nonmonotonic == 2 and c.rows_accounted()
    assert any("imu0/data.csv: line 2: stamp 0 lies" in n for n in report.notes)
    with pytest.raises(DataError, match="stamp 0 lies .* from every other row") as info:
        read_stamped_csv(f, 1, StreamCounts(), "strict")
    assert info.value.line == 2
    gap = [s if k < 20 else s + 5 * 10**9 for k, s in enumerate(t[1:-1])]     # a pause is no corruption
    f.write_text("".join(f"{s},0\n" for s in gap[:3]) + "".join(f"{s},0\n" for s in gap[3:]))
    assert read_stamped_csv(f, 1, StreamCounts()).t_ns.shape[0] == 38
