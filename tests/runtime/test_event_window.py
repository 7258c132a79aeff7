"""`davio run|live|calibrate --seconds S` (runtime.event_window): the first S seconds of data where both
streams run."""
from __future__ import annotations

import numpy as np

from runtime.event_window import first_seconds
from runtime.events import Frame, ImuSample

T = 1_600_000_000_000_000_000     # a recording's stamps (2020)


def _imu(t: int) -> ImuSample:
    return ImuSample(t, np.zeros(3), np.array([0.0, 0.0, 9.81]))


def _frame(t: int) -> Frame:
    return Frame(t, np.zeros((4, 4), np.uint8))


def _stream(imu_from: int, frames_from: int, seconds: float) -> list:
    imu = [_imu(imu_from + k * 5_000_000) for k in range(int(seconds * 200))]
    cam = [_frame(frames_from + k * 50_000_000) for k in range(int(seconds * 20))]
    return sorted(imu + cam, key=lambda e: (e.t_ns, isinstance(e, Frame)))


def test_counted_from_where_both_streams_have_begun() -> None:
    events = _stream(T, T + 100_000_000, 10.0)        # the IMU 0.1 s before the first image
    kept = list(first_seconds(iter(events), 2.0))
    assert kept == [e for e in events if e.t_ns <= T + 100_000_000 + 2_000_000_000]


def test_a_corrupt_first_stamp_does_not_use_up_the_span() -> None:
    """A first image stamped 0 ns (a corrupt row) lies 50 years before the data: counting from it kept
    nothing of the recording ('found no start in 0.0 s of data')."""
    events = [_frame(0)] + _stream(T, T + 100_000_000, 10.0)
    kept = list(first_seconds(iter(events), 2.0))
    assert kept[0].t_ns == 0 and kept[1:] == [e for e in events[1:] if e.t_ns <= T + 2_000_000_000]
    assert sum(isinstance(e, Frame) for e in kept) == 1 + 39     # images from T + 0.1 s to T + 2 s


def test_a_stream_of_one_kind_alone_still_ends() -> None:
    imu = [_imu(T + k * 5_000_000) for k in range(2000)]          # 10 s, no image ever
    kept = list(first_seconds(iter(imu), 2.0))
    assert kept == [e for e in imu if e.t_ns <= T + 2_000_000_000]
