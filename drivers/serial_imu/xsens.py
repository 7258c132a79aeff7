"""Xsens Xbus MTData2: a resynchronising frame parser, an encoder, and the config commands.

Frame (notes/drivers.md §2): `FA | FF | MID | LEN | [u16 BE extended length if LEN == FF] | DATA | CS`
with `sum(FF .. CS) & 0xFF == 0`. MTData2 (MID 0x36) DATA is a run of `{DataID u16 BE, size u8,
big-endian payload}`. The data ID's low nibble encodes the precision (bits 0-1: 0 = float32,
3 = float64; the fixed-point formats are not supported) and the coordinate frame (bits 2-3), so
types are matched with `id & 0xFFF0`:

| id     | name           | payload                                   |
|--------|----------------|-------------------------------------------|
| 0x1020 | PacketCounter  | u16, wraps at 65536 (unwrapped here)      |
| 0x1060 | SampleTimeFine | u32, 0.1 ms ticks, wraps (unwrapped here) |
| 0x4020 | Acceleration   | 3 x f32 (or f64) m/s^2                    |
| 0x8020 | RateOfTurn     | 3 x f32 (or f64) rad/s                    |

A packet becomes a `DeviceSample` when it holds acceleration, rate of turn and SampleTimeFine (the
device clock the host clock is fitted against); others are counted and dropped. The parser never
waits for more than `max_payload` bytes behind a header, so a fake header in line noise cannot
stall it; a frame whose checksum fails is skipped one byte at a time so that valid frames inside
it are still found.

The command builders (`go_to_config`, `set_output_configuration`, `go_to_measurement`) are only
sent when the user asks the reader to configure the device; by default it just listens.
"""
from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Sequence

from drivers.serial_imu.clock import Unwrapper
from drivers.serial_imu.common import DeviceSample, ParserCounts, SeqTracker

PREAMBLE = 0xFA
BUS_ID = 0xFF
MID_MTDATA2 = 0x36
MID_GOTO_CONFIG = 0x30
MID_GOTO_MEASUREMENT = 0x10
MID_SET_OUTPUT_CONFIGURATION = 0xC0
MID_ERROR = 0x42

XDI_PACKET_COUNTER = 0x1020
XDI_SAMPLE_TIME_FINE = 0x1060
XDI_ACCELERATION = 0x4020
XDI_RATE_OF_TURN = 0x8020
PRECISION_FLOAT32 = 0x0
PRECISION_FLOAT64 = 0x3
SAMPLE_TIME_FINE_NS = 100_000
"""one SampleTimeFine tick (10 kHz)"""
FREQ_EVERY_PACKET = 0xFFFF
"""output frequency given to counter/time fields in SetOutputConfiguration: sent with every packet"""

DEFAULT_MAX_PAYLOAD = 128
"""largest DATA accepted; the four fields above in float64 need 66 bytes, in float32 42"""
XBUS_MAX_PAYLOAD = 2048
"""largest DATA an Xbus frame carries (extended length): what a device left in its own output
configuration may send (orientation, delta-q/v, magnetic field, status... beside the four fields). The
serial reader accepts it when it only listens (`serial_imu.reader.make_parser`). A fake header (garbage
that reads FA FF MID FF + a long length) is dropped as soon as two valid frames in a row follow it
inside the bytes it claims (`XbusFramer`); it held the parser for the whole length before (0.2 s of
samples at 200 Hz), and the live merge then dropped the IMU samples it had delayed."""


def checksum(body: bytes | bytearray) -> int:
    """The Xbus checksum byte of `BID MID LEN [ext] DATA`: makes the sum of all of them and it 0 mod 256."""
    return (-sum(body)) & 0xFF


def encode_frame(mid: int, data: bytes = b"") -> bytes:
    """An Xbus frame (extended length when DATA is 255 bytes or more)."""
    if len(data) < 0xFF:
        body = bytes([BUS_ID, mid & 0xFF, len(data)]) + bytes(data)
    else:
        if len(data) > 0xFFFF:
            raise ValueError("Xbus DATA is at most 65535 bytes")
        body = bytes([BUS_ID, mid & 0xFF, 0xFF]) + struct.pack(">H", len(data)) + bytes(data)
    return bytes([PREAMBLE]) + body + bytes([checksum(body)])


def encode_field(data_id: int, payload: bytes) -> bytes:
    """One MTData2 field: `{DataID u16 BE, size u8, payload}`."""
    if len(payload) > 0xFF:
        raise ValueError("an MTData2 field holds at most 255 bytes")
    return struct.pack(">HB", data_id, len(payload)) + payload


def encode_mtdata2(counter: int | None = None, sample_time_fine: int | None = None,
                   accel: Sequence[float] | None = None, gyro: Sequence[float] | None = None,
                   precision: str = "f32", extra: Iterable[tuple[int, bytes]] = ()) -> bytes:
    """An MTData2 frame (for tests and simulators).

    Args:
        counter: PacketCounter, taken mod 65536.
        sample_time_fine: SampleTimeFine in 0.1 ms ticks, taken mod 2^32.
        accel, gyro: 3 values, m/s^2 and rad/s.
        precision: "f32" or "f64".
        extra: further (data_id, payload) fields, e.g. unknown ones.
    """
    if precision not in ("f32", "f64"):
        raise ValueError("precision must be 'f32' or 'f64'")
    fmt, nib = (">3f", PRECISION_FLOAT32) if precision == "f32" else (">3d", PRECISION_FLOAT64)
    data = b""
    if counter is not None:
        data += encode_field(XDI_PACKET_COUNTER, struct.pack(">H", counter % 0x10000))
    if sample_time_fine is not None:
        data += encode_field(XDI_SAMPLE_TIME_FINE, struct.pack(">I", sample_time_fine % 0x1_0000_0000))
    if accel is not None:
        data += encode_field(XDI_ACCELERATION | nib, struct.pack(fmt, *accel))
    if gyro is not None:
        data += encode_field(XDI_RATE_OF_TURN | nib, struct.pack(fmt, *gyro))
    for data_id, payload in extra:
        data += encode_field(data_id, payload)
    return encode_frame(MID_MTDATA2, data)


# --- configuration commands (sent only when asked) ----------------------------------------------
def go_to_config() -> bytes:
    """GoToConfig: `FA FF 30 00 D1`."""
    return encode_frame(MID_GOTO_CONFIG)


def go_to_measurement() -> bytes:
    """GoToMeasurement: `FA FF 10 00 F1`."""
    return encode_frame(MID_GOTO_MEASUREMENT)


def set_output_configuration(rate_hz: int = 400, precision: str = "f32",
                             outputs: Sequence[tuple[int, int]] | None = None) -> bytes:
    """SetOutputConfiguration (MID 0xC0): {DataID u16 BE, frequency u16 BE} pairs.

    Default: PacketCounter and SampleTimeFine with every packet (0xFFFF), Acceleration and
    RateOfTurn at `rate_hz` in `precision`. Pass `outputs` to send an explicit list instead.
    """
    if outputs is None:
        nib = PRECISION_FLOAT32 if precision == "f32" else PRECISION_FLOAT64
        outputs = [(XDI_PACKET_COUNTER, FREQ_EVERY_PACKET), (XDI_SAMPLE_TIME_FINE, FREQ_EVERY_PACKET),
                   (XDI_ACCELERATION | nib, rate_hz), (XDI_RATE_OF_TURN | nib, rate_hz)]
    return encode_frame(MID_SET_OUTPUT_CONFIGURATION, b"".join(struct.pack(">HH", i, f) for i, f in outputs))


# --- parsing ------------------------------------------------------------------------------------
class XbusFramer:
    """Splits a byte stream into Xbus messages `(mid, data)`, resynchronising on errors.

    Counts into `counts`: bytes_in, bytes_framed, bytes_skipped, frames, checksum_errors,
    oversized_headers, partial_packets (in `finish`).
    """

    def __init__(self, counts: ParserCounts, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        if max_payload < 1:
            raise ValueError("max_payload must be >= 1")
        self.counts = counts
        self.max_payload = int(max_payload)
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes buffered, waiting for the rest of a frame."""
        return len(self._buf)

    def _skip(self, n: int) -> None:
        del self._buf[:n]
        self.counts.bytes_skipped += n

    def feed(self, data: bytes | bytearray) -> list[tuple[int, bytes]]:
        """Add bytes; returns the complete, checksum-valid messages now available."""
        self.counts.bytes_in += len(data)
        self._buf += data
        out: list[tuple[int, bytes]] = []
        buf = self._buf
        c = self.counts
        while True:
            i = buf.find(b"\xfa\xff")
            if i < 0:  # keep a trailing FA: it may be the start of the next frame
                keep = 1 if buf[-1:] == b"\xfa" else 0
                self._skip(len(buf) - keep)
                return out
            if i:
                self._skip(i)
            if len(buf) < 4:
                return out
            n = buf[3]
            head = 4
            if n == 0xFF:
                if len(buf) < 6:
                    return out
                n = (buf[4] << 8) | buf[5]
                head = 6
            if n > self.max_payload:
                c.oversized_headers += 1
                self._skip(1)
                continue
            total = head + n + 1
            if len(buf) < total:
                if self._contradicted(buf):      # two valid frames follow inside it: a fake header
                    c.oversized_headers += 1
                    self._skip(1)
                    continue
                return out
            if sum(buf[1:total]) & 0xFF:
                c.checksum_errors += 1
                self._skip(1)
                continue
            out.append((buf[2], bytes(buf[head:head + n])))
            c.frames += 1
            c.bytes_framed += total
            del buf[:total]

    def _frame_at(self, buf: bytearray, j: int) -> int | None:
        """Length of the complete, checksum-valid frame starting at `j`, or None."""
        if len(buf) < j + 4:
            return None
        n, head = buf[j + 3], 4
        if n == 0xFF:
            if len(buf) < j + 6:
                return None
            n, head = (buf[j + 4] << 8) | buf[j + 5], 6
        total = head + n + 1
        if n > self.max_payload or len(buf) < j + total or sum(buf[j + 1:j + total]) & 0xFF:
            return None
        return total

    def _contradicted(self, buf: bytearray) -> bool:
        """Whether the incomplete frame at the start of `buf` holds two valid frames in a row (at FA FF,
        the second right after the first): its length is garbage. A real frame's data holding such a
        pair (two checksums matching by chance) is not to be expected."""
        j = buf.find(b"\xfa\xff", 2)
        while j >= 0:
            first = self._frame_at(buf, j)
            if first is not None and buf[j + first:j + first + 2] == b"\xfa\xff" \
                    and self._frame_at(buf, j + first) is not None:
                return True
            j = buf.find(b"\xfa\xff", j + 1)
        return False

    def finish(self) -> None:
        """End of stream: a buffered frame start is a partial packet; its bytes count as skipped."""
        if self._buf:
            if self._buf[:2] == b"\xfa\xff" or self._buf == b"\xfa":
                self.counts.partial_packets += 1
            self._skip(len(self._buf))


_VEC_FORMATS = {(PRECISION_FLOAT32, 12): ">3f", (PRECISION_FLOAT64, 24): ">3d"}


class MalformedField(ValueError):
    """An MTData2 field whose size or precision does not match its type."""


def decode_mtdata2(data: bytes) -> dict[int, object]:
    """The fields of one MTData2 DATA block: {id & 0xFFF0: value}.

    Values: PacketCounter and SampleTimeFine as int, Acceleration and RateOfTurn as 3-tuples of
    float; unknown fields as their raw bytes. Raises MalformedField on a truncated field or a
    known field of the wrong size/precision.
    """
    fields: dict[int, object] = {}
    i, n = 0, len(data)
    while i < n:
        if i + 3 > n:
            raise MalformedField(f"truncated field header at byte {i}")
        data_id, size = struct.unpack_from(">HB", data, i)
        i += 3
        if i + size > n:
            raise MalformedField(f"field 0x{data_id:04X} of {size} bytes overruns the packet")
        payload = data[i:i + size]
        i += size
        kind = data_id & 0xFFF0
        if kind == XDI_PACKET_COUNTER:
            if size != 2:
                raise MalformedField(f"PacketCounter of {size} bytes")
            fields[kind] = struct.unpack(">H", payload)[0]
        elif kind == XDI_SAMPLE_TIME_FINE:
            if size != 4:
                raise MalformedField(f"SampleTimeFine of {size} bytes")
            fields[kind] = struct.unpack(">I", payload)[0]
        elif kind in (XDI_ACCELERATION, XDI_RATE_OF_TURN):
            fmt = _VEC_FORMATS.get((data_id & 0x3, size))
            if fmt is None:
                raise MalformedField(f"field 0x{data_id:04X}: unsupported precision or size {size}")
            fields[kind] = struct.unpack(fmt, payload)
        else:
            fields[kind] = bytes(payload)
    return fields


class XsensParser:
    """Bytes in, `DeviceSample`s out (MTData2 with accel, gyro and SampleTimeFine).

    Args:
        max_payload: largest Xbus DATA accepted (a longer announced length is a fake header).
    """

    name = "xsens"

    def __init__(self, max_payload: int = DEFAULT_MAX_PAYLOAD) -> None:
        self.counts = ParserCounts()
        self.framer = XbusFramer(self.counts, max_payload)
        self._time = Unwrapper(1 << 32)
        self._seq = Unwrapper(1 << 16)
        self._gaps = SeqTracker(self.counts)
        self.last_missing: str | None = None
        """what the latest packet that was dropped for missing fields lacked (for error messages)"""
        self.device_errors: list[int] = []
        """error codes of Xbus Error (0x42) messages received"""

    def feed(self, data: bytes | bytearray) -> list[DeviceSample]:
        out: list[DeviceSample] = []
        c = self.counts
        for mid, payload in self.framer.feed(data):
            if mid != MID_MTDATA2:
                c.unknown_packets += 1
                if mid == MID_ERROR and payload:
                    self.device_errors.append(payload[0])
                continue
            try:
                fields = decode_mtdata2(payload)
            except MalformedField:
                c.malformed_packets += 1
                continue
            acc = fields.get(XDI_ACCELERATION)
            gyr = fields.get(XDI_RATE_OF_TURN)
            stf = fields.get(XDI_SAMPLE_TIME_FINE)
            if acc is None and gyr is None and stf is None and XDI_PACKET_COUNTER not in fields:
                c.unknown_packets += 1
                continue
            if acc is None or gyr is None or stf is None:
                c.missing_fields += 1
                names = ("Acceleration (0x4020)", "RateOfTurn (0x8020)", "SampleTimeFine (0x1060)")
                self.last_missing = ", ".join(nm for nm, v in zip(names, (acc, gyr, stf), strict=True)
                                              if v is None)
                continue
            if not all(math.isfinite(v) for v in (*acc, *gyr)):  # type: ignore[misc]
                c.nonfinite += 1
                continue
            seq = None
            if XDI_PACKET_COUNTER in fields:
                seq = self._seq.update(fields[XDI_PACKET_COUNTER])  # type: ignore[arg-type]
                self._gaps.update(seq)
            t_dev = self._time.update(stf) * SAMPLE_TIME_FINE_NS  # type: ignore[arg-type]
            out.append(DeviceSample(seq, t_dev, tuple(gyr), tuple(acc)))  # type: ignore[arg-type]
            c.samples += 1
        return out

    def finish(self) -> None:
        """End of stream (stop or unplug): count a cut-off frame."""
        self.framer.finish()

    @property
    def pending(self) -> int:
        return self.framer.pending
