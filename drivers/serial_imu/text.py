"""A simple ASCII IMU protocol for microcontroller IMUs (Arduino, ESP32, ...).

One line per sample:

    $IMU,<seq>,<t_dev_us>,<ax>,<ay>,<az>,<gx>,<gy>,<gz>*HH\\r\\n

- `seq`: the device's sample counter, unsigned decimal (gaps are counted; 32-bit wrap handled).
- `t_dev_us`: device time of the sample in microseconds, unsigned decimal; a 32-bit counter that
  wraps (Arduino `micros()` wraps every 71.6 min) is unwrapped. Both are required: the host
  clock is fitted against the device time.
- `ax ay az`: specific force in m/s^2; `gx gy gz`: angular rate in rad/s; decimal floats.
- `HH`: NMEA checksum, the XOR of every byte between `$` and `*`, two hex digits (either case).
  Required. The line ends with `\\r\\n` (a bare `\\n` or `\\r` is accepted). Numbers are plain decimals
  (no digit groups `1_0`); a line repeating the previous one's seq and time is dropped
  (`duplicates`).

Example: `$IMU,1,2500,0.1,0.2,9.81,0.01,-0.02,0.03*HH`. Lines longer than `max_line` bytes are
resynchronised at the next `$`; a line whose checksum verifies but whose tag is not `IMU` is counted
as unknown and ignored, so a device may interleave other sentences.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from functools import reduce

from drivers.serial_imu.clock import Unwrapper
from drivers.serial_imu.common import DeviceSample, ParserCounts, SeqTracker

TAG = "IMU"
DEFAULT_MAX_LINE = 256
_HEX = frozenset(b"0123456789abcdefABCDEF")


def nmea_checksum(body: bytes | str) -> int:
    """XOR of the bytes of `body` (the text between `$` and `*`)."""
    if isinstance(body, str):
        body = body.encode("ascii")
    return reduce(lambda a, b: a ^ b, body, 0)


def encode_line(seq: int, t_dev_us: int, accel: Sequence[float], gyro: Sequence[float],
                float_format: str = ".9g") -> bytes:
    """One protocol line, `$IMU,...*HH\\r\\n` (for tests and simulators)."""
    vals = ",".join(format(float(v), float_format) for v in (*accel, *gyro))
    body = f"{TAG},{int(seq)},{int(t_dev_us)},{vals}"
    return f"${body}*{nmea_checksum(body):02X}\r\n".encode("ascii")


class TextParser:
    """Bytes in, `DeviceSample`s out, for the `$IMU` ASCII protocol; same counters as the Xsens parser.

    Args:
        max_line: longest line accepted, in bytes (a longer one is resynchronised).
    """

    name = "text"

    def __init__(self, max_line: int = DEFAULT_MAX_LINE) -> None:
        self.counts = ParserCounts()
        self.max_line = int(max_line)
        self._buf = bytearray()
        self._time = Unwrapper(1 << 32)
        self._seq = Unwrapper(1 << 32)
        self._gaps = SeqTracker(self.counts)
        self.last_missing: str | None = None
        self._last_raw: tuple[int, int] | None = None
        self._after_cr = False

    @property
    def pending(self) -> int:
        return len(self._buf)

    def _skip(self, n: int) -> None:
        del self._buf[:n]
        self.counts.bytes_skipped += n

    def feed(self, data: bytes | bytearray) -> list[DeviceSample]:
        self.counts.bytes_in += len(data)
        self._buf += data
        buf = self._buf
        c = self.counts
        out: list[DeviceSample] = []
        while True:
            if self._after_cr and buf[:1] == b"\n":     # the LF of a CRLF split across reads
                del buf[:1]
                c.bytes_framed += 1
            if buf:
                self._after_cr = False
            i = buf.find(b"$")
            if i < 0:
                self._skip(len(buf))
                return out
            if i:
                self._skip(i)
            ends = [e for e in (buf.find(b"\n", 1, self.max_line), buf.find(b"\r", 1, self.max_line))
                    if e >= 0]
            end = min(ends) if ends else -1      # LF, CRLF or CR alone ends a line
            if end >= 0 and buf[end] == 0x0D:
                if buf[end + 1:end + 2] == b"\n":
                    end += 1
                elif end + 1 == len(buf):
                    self._after_cr = True        # its LF, if any, comes with the next read
            nxt = buf.find(b"$", 1, end if end >= 0 else self.max_line)
            if nxt > 0:  # a new sentence starts before this one ended: this one was cut
                self._skip(nxt)
                continue
            if end < 0:
                if len(buf) >= self.max_line:
                    c.oversized_headers += 1
                    self._skip(1)
                    continue
                return out
            line = bytes(buf[:end + 1])
            sample = self._line(line)
            if sample is False:
                self._skip(end + 1)
                continue
            c.frames += 1
            c.bytes_framed += end + 1
            del buf[:end + 1]
            if sample is not None:
                out.append(sample)
                c.samples += 1

    def _line(self, line: bytes) -> DeviceSample | None | bool:
        """A parsed sample; None for a valid line that yields none (counted); False for a bad checksum."""
        c = self.counts
        core = line.rstrip(b"\r\n")
        star = core.rfind(b"*")
        if star < 0 or len(core) - star != 3 or not all(ch in _HEX for ch in core[star + 1:]):
            c.checksum_errors += 1  # no checksum: cannot be trusted
            return False
        body = core[1:star]
        if nmea_checksum(body) != int(core[star + 1:], 16):
            c.checksum_errors += 1
            return False
        try:
            parts = body.decode("ascii").split(",")
        except UnicodeDecodeError:
            c.malformed_packets += 1
            return None
        if parts[0] != TAG:
            c.unknown_packets += 1
            return None
        if len(parts) != 9:
            if len(parts) < 9:
                c.missing_fields += 1
                self.last_missing = f"{9 - len(parts)} of seq, t_dev_us, ax..gz"
            else:
                c.malformed_packets += 1
            return None
        try:
            if any("_" in p for p in parts[1:]):        # int("1_0") is 10: no device means it
                raise ValueError
            seq, t_us = int(parts[1]), int(parts[2])
            vals = [float(p) for p in parts[3:9]]
        except ValueError:
            c.malformed_packets += 1
            return None
        if seq < 0 or t_us < 0:
            c.malformed_packets += 1
            return None
        if not all(math.isfinite(v) for v in vals):
            c.nonfinite += 1
            return None
        if (seq, t_us) == self._last_raw:      # a repeated line: it would be stamped 1 ns later
            c.duplicates += 1
            return None
        self._last_raw = (seq, t_us)
        useq = self._seq.update(seq)
        self._gaps.update(useq)
        t_dev = self._time.update(t_us) * 1000
        return DeviceSample(useq, t_dev, (vals[3], vals[4], vals[5]), (vals[0], vals[1], vals[2]))

    def finish(self) -> None:
        """End of stream: a buffered line start is a partial packet; its bytes count as skipped."""
        if self._buf:
            if self._buf[:1] == b"$":
                self.counts.partial_packets += 1
            self._skip(len(self._buf))
