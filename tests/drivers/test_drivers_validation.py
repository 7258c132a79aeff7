"""Stamped-CSV validation helpers: the fewest-rows monotonic repair against brute force."""
from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.base import StreamCounts
from drivers.validation import count_gaps, monotonic_keep_mask, read_stamped_csv


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
    np.testing.assert_array_equal(rows.t_ns, [10, 20, 70])
    np.testing.assert_array_equal(rows.line, [2, 3, 10])
    assert (c.dropped_duplicate, c.dropped_nonmonotonic, c.dropped_nonfinite, c.malformed_lines,
            c.truncated_lines) == (1, 1, 1, 2, 1)
    assert c.lines == 9 and c.rows_accounted()


def test_gap_counting() -> None:
    c = StreamCounts()
    t = np.array([0, 10, 20, 30, 60, 70, 80, 95], dtype=np.int64)
    count_gaps(t, c)
    assert c.median_period_ns == 10 and c.gaps == 1 and c.missing_estimated == 2
