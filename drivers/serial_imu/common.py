"""What both serial IMU protocols produce: device samples and the parser counters.

A parser turns bytes into `DeviceSample`s stamped with the *device* clock (unwrapped, int64 ns);
`clock.DeviceClock` later maps that device time onto the host's `time.monotonic_ns()` clock.
Every byte fed to a parser is accounted for:
`bytes_in == bytes_framed + bytes_skipped + pending` (pending = bytes still buffered).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True, slots=True)
class DeviceSample:
    """One IMU sample as the device sent it.

    Attributes:
        seq: the device's unwrapped sample/packet counter, or None when the packet has none.
        t_dev_ns: device time, unwrapped, int64 nanoseconds (device clock, arbitrary origin).
        gyro: (wx, wy, wz) rad/s.
        accel: (ax, ay, az) m/s^2.
    """

    seq: int | None
    t_dev_ns: int
    gyro: tuple[float, float, float]
    accel: tuple[float, float, float]


@dataclass
class ParserCounts:
    """Counters of one serial stream parser (all protocols share them)."""

    bytes_in: int = 0
    """bytes fed to the parser"""
    bytes_framed: int = 0
    """bytes inside frames/lines whose checksum verified"""
    bytes_skipped: int = 0
    """bytes discarded while resynchronising: garbage, corrupt frames, fake headers, cut-off tails"""
    frames: int = 0
    """frames/lines with a valid checksum (any message type)"""
    samples: int = 0
    """IMU samples produced"""
    checksum_errors: int = 0
    """candidate frames/lines whose checksum failed"""
    oversized_headers: int = 0
    """headers announcing more than the configured maximum length, or a length that the valid frames
    after them contradict (fake headers in garbage)"""
    partial_packets: int = 0
    """a frame/line cut off by the end of the stream (counted by `finish()`)"""
    unknown_packets: int = 0
    """valid frames of another message type (acks, errors, ...) or with no known field"""
    missing_fields: int = 0
    """valid data packets lacking accel, gyro or device time (dropped)"""
    malformed_packets: int = 0
    """valid-checksum packets whose content does not parse (bad field size, bad number, ...)"""
    nonfinite: int = 0
    """packets holding NaN or Inf (dropped)"""
    duplicates: int = 0
    """packets repeating the previous packet's counter and device time (dropped)"""
    seq_gaps: int = 0
    """discontinuities of the device sample counter (samples lost upstream or a reset)"""
    missing_estimated: int = 0
    """samples missing inside forward counter gaps"""

    def as_dict(self) -> dict:
        """JSON-ready copy."""
        return asdict(self)


class SeqTracker:
    """Counts gaps of an unwrapped sample counter."""

    def __init__(self, counts: ParserCounts, max_gap: int = 100_000) -> None:
        self._counts = counts
        self._last: int | None = None
        self._max_gap = max_gap

    def update(self, seq: int | None) -> None:
        if seq is None:
            return
        if self._last is not None and seq != self._last + 1:
            self._counts.seq_gaps += 1
            missing = seq - self._last - 1
            if 0 < missing <= self._max_gap:
                self._counts.missing_estimated += missing
        self._last = seq
