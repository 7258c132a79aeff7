"""clock_reset: a second clock in a stamped stream is refused; what can be repaired is not.

Streams are built here from known segments, so the expected answer is known by construction."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.validation import clock_reset

T0, P = 10**18, 5_000_000                      # 200 Hz
T = T0 + np.arange(10_000, dtype=np.int64) * P  # 50 s
V = np.random.default_rng(0).normal(size=(10_000, 6))


def test_a_reset_to_an_earlier_time_is_found_where_it_happens() -> None:
    t = T.copy()
    t[6000:] -= 1000 * 10**9                    # apart from the first clock's span
    assert clock_reset(t, V) == 6000
    inside = np.r_[T[:8000], T[1000:3000]]      # the second clock restarts inside the first's span
    other = np.random.default_rng(1).normal(size=(10_000, 6))   # with other data on the same grid
    assert clock_reset(inside, other) == 8000


@pytest.mark.parametrize("name,t,v", [
    ("block written twice", np.r_[T[:6000], T[2000:6000], T[6000:]],
     np.r_[V[:6000], V[2000:6000], V[6000:]]),
    ("20 s chunk written late", np.r_[T[:2000], T[6000:], T[2000:6000]],
     np.r_[V[:2000], V[6000:], V[2000:6000]]),
    ("reversed file", T[::-1].copy(), V[::-1].copy()),
    ("one stamp far behind", np.r_[T[:5000], T[5000:5001] - 10**12, T[5001:]], V),
    ("one stamp far ahead", np.r_[T[:5000], T[5000:5001] + 10**12, T[5001:]], V),
    ("a 30 s dropout", np.r_[T[:3000], T[3000:] + 30 * 10**9], V),
])
def test_what_can_be_repaired_is_no_reset(name: str, t: np.ndarray, v: np.ndarray) -> None:
    assert clock_reset(t, v) is None, name
