"""The span of stamps behind the newest one: a clock that went back, against stray and repeated stamps."""
from __future__ import annotations

from runtime.imu.stamps_back import StampsBehind


def test_a_clock_that_went_back_spans_its_jump_stray_and_repeated_stamps_span_nothing() -> None:
    behind = StampsBehind(max_step_ns=50)
    assert behind.passed() == 0
    for t in range(7_000, 10_000, 5):          # newest was 10_000: the clock went back 3_000 and ran on
        behind.behind(t)
    assert behind.passed() == 2_995
    assert behind.passed() == 0                # cleared
    behind.behind(4_000)                       # one stray stamp, then on past the newest
    assert behind.passed() == 0
    behind.behind(4_000)                       # a stray, then a repeat of the newest (10_000): no clock ran
    behind.behind(10_000)
    assert behind.passed() == 0
    for t in (7_000, 7_005, 9_000, 9_005):     # samples lost within the run: only steps at the rate count
        behind.behind(t)
    assert behind.passed() == 10
