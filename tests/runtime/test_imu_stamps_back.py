"""The span of stamps behind the newest one: a clock that went back, against a stray stamp."""
from __future__ import annotations

from runtime.imu.stamps_back import StampsBehind


def test_a_clock_that_went_back_spans_its_jump_a_stray_stamp_spans_nothing() -> None:
    behind = StampsBehind()
    assert behind.passed() == 0
    for t in range(7_000, 10_000, 5):          # newest was 10_000: the clock went back 3_000 and ran on
        behind.behind(t)
    assert behind.passed() == 2_995
    assert behind.passed() == 0                # cleared
    behind.behind(4_000)                       # one stray stamp, then on past the newest
    assert behind.passed() == 0
