"""Xsens Xbus MTData2 parser: resynchronisation, exact counters, unwrapping, the encoder and commands."""
from __future__ import annotations

import random
import struct

import numpy as np
import pytest

from drivers.serial_imu.xsens import (
    XBUS_MAX_PAYLOAD,
    XsensParser,
    decode_mtdata2,
    encode_frame,
    encode_mtdata2,
    go_to_config,
    go_to_measurement,
    set_output_configuration,
)

FRAME_LEN = 47  # counter 5 + time 7 + accel 15 + gyro 15 + header 4 + checksum 1 (notes/drivers.md §2)


def values(k: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Accel and gyro of sample k, exactly representable in float32."""
    return (0.5 * k, -1.25, 9.75), (k / 64.0, -k / 128.0, 0.125)


def frame(k: int, stf0: int = 1000, counter0: int = 0) -> bytes:
    acc, gyr = values(k)
    return encode_mtdata2(counter=counter0 + k, sample_time_fine=stf0 + 25 * k, accel=acc, gyro=gyr)


def feed_chunked(parser: XsensParser, data: bytes, seed: int = 0) -> list:
    rng = random.Random(seed)
    out, i = [], 0
    while i < len(data):
        n = rng.randint(1, 9)
        out += parser.feed(data[i:i + n])
        i += n
    return out


def test_commands_and_frame_bytes_match_the_spec() -> None:
    assert go_to_config() == bytes.fromhex("FAFF3000D1")
    assert go_to_measurement() == bytes.fromhex("FAFF1000F1")
    cfg = set_output_configuration(400)
    assert cfg[:4] == bytes.fromhex("FAFFC010")
    assert cfg[4:-1] == bytes.fromhex("1020FFFF" "1060FFFF" "40200190" "80200190")
    assert sum(cfg[1:]) % 256 == 0
    # an MTData2 frame built by hand, byte by byte
    body = (bytes([0xFF, 0x36, 42]) + bytes.fromhex("102002") + struct.pack(">H", 7)
            + bytes.fromhex("106004") + struct.pack(">I", 123456)
            + bytes.fromhex("40200C") + struct.pack(">3f", 1.0, 2.0, 3.0)
            + bytes.fromhex("80200C") + struct.pack(">3f", 0.5, 0.25, -0.5))
    expected = b"\xfa" + body + bytes([(256 - sum(body) % 256) % 256])
    got = encode_mtdata2(counter=7, sample_time_fine=123456, accel=(1, 2, 3), gyro=(0.5, 0.25, -0.5))
    assert got == expected and len(got) == FRAME_LEN
    ext = encode_frame(0x36, bytes(300))
    assert ext[3] == 0xFF and ext[4:6] == struct.pack(">H", 300) and sum(ext[1:]) % 256 == 0


def test_garbage_corrupt_fake_headers_and_partial_are_counted_exactly() -> None:
    frames = [frame(k) for k in range(40)]
    corrupt = bytearray(frames[10])
    corrupt[20] ^= 0x40  # a data byte flipped: checksum fails
    assert b"\xfa\xff" not in bytes(corrupt[1:])
    garbage = b"\x01\x02\x03\xfa\x00\x55"                     # 6 bytes, no FA FF
    fake_len = b"\xfa\xff\x36\xfa"                             # LEN 250 > max 128
    fake_ext = b"\xfa\xff\x36\xff\x10\x00"                     # extended LEN 4096
    ack = encode_frame(0x31)                                   # GoToConfigAck: valid, not MTData2
    no_gyro = encode_mtdata2(counter=99, sample_time_fine=5, accel=(1, 2, 3))
    partial = frames[39][:20]
    stream = (garbage + b"".join(frames[:5]) + fake_len + b"".join(frames[5:10]) + bytes(corrupt)
              + b"".join(frames[11:20]) + fake_ext + ack + b"".join(frames[20:30]) + no_gyro
              + b"".join(frames[30:39]) + partial)
    for chunked in (False, True):
        p = XsensParser()
        samples = feed_chunked(p, stream, seed=3) if chunked else p.feed(stream)
        p.finish()
        c = p.counts
        kept = [k for k in range(39) if k != 10]
        assert [round(s.accel[0] * 2) for s in samples] == kept
        for s, k in zip(samples, kept, strict=True):
            acc, gyr = values(k)
            assert s.accel == acc and s.gyro == gyr
            assert s.t_dev_ns == (1000 + 25 * k) * 100_000
        assert c.samples == 38 and c.checksum_errors == 1 and c.oversized_headers == 2
        assert c.unknown_packets == 1 and c.missing_fields == 1 and c.partial_packets == 1
        assert c.frames == 38 + 2 and c.malformed_packets == 0
        assert c.bytes_skipped == len(garbage) + FRAME_LEN + len(fake_len) + len(fake_ext) + len(partial)
        assert c.bytes_in == len(stream) == c.bytes_framed + c.bytes_skipped
        # frame 10 (corrupt) was lost upstream of the counter; the no-gyro packet carried no sample
        assert c.seq_gaps == 1 and c.missing_estimated == 1
        assert p.last_missing == "RateOfTurn (0x8020)"


def test_fake_header_does_not_stall_the_next_frame() -> None:
    p = XsensParser(max_payload=64)
    assert p.feed(b"\xfa\xff\x36\x50") == []         # LEN 80 > 64: rejected at once
    out = p.feed(frame(0))
    assert len(out) == 1 and p.counts.oversized_headers == 1 and p.pending == 0


def test_a_fake_extended_header_is_dropped_once_two_frames_follow() -> None:
    """Garbage reading FA FF 36 FF 07 D0 (a 2000-byte frame) held every frame after it until 2000 bytes had
    come: 0.2 s of samples at 200 Hz, which the live merge then dropped as late."""
    p = XsensParser(max_payload=XBUS_MAX_PAYLOAD)
    got = p.feed(frame(0) + b"\xfa\xff\x36\xff\x07\xd0")
    for k in range(1, 30):                      # one frame per read, as the device sends them
        got += p.feed(frame(k))
        assert len(got) >= k                    # frame k-1 is out once frame k has come: one frame late
    assert [round(s.accel[0] * 2) for s in got] == list(range(len(got))) and len(got) == 30
    assert p.counts.oversized_headers == 1 and p.counts.bytes_skipped == 6
    real = XsensParser(max_payload=XBUS_MAX_PAYLOAD)   # a real 1000-byte frame fed in pieces still comes
    big = encode_mtdata2(counter=1, sample_time_fine=5, accel=(1, 2, 3), gyro=(4, 5, 6),
                         extra=[(0x2010, frame(k)[:40]) for k in range(25)])     # frames inside its data
    assert len(big) > 1000 and b"\xfa\xff" in big[4:]
    assert sum(len(real.feed(big[i:i + 100])) for i in range(0, len(big), 100)) == 1
    assert real.counts.oversized_headers == 0


def test_a_listening_reader_takes_frames_with_more_fields_than_the_four() -> None:
    """A device left in its own output configuration sends MTData2 frames with more fields (here 146
    bytes of DATA: orientation, delta-q, delta-v, magnetic field, status, temperature beside the four).
    The reader that only listens parses them; the one that configured the device keeps the tight cap."""
    from drivers.serial_imu.reader import make_parser

    extra = [(0x2010, bytes(16)), (0x8030, bytes(16)), (0x4010, bytes(12)), (0xC020, bytes(12)),
             (0xE020, bytes(4)), (0x0810, bytes(4)), (0x2030, bytes(12)), (0x4030, bytes(12)),
             (0x3010, bytes(4))]
    frames = [encode_mtdata2(counter=k, sample_time_fine=1000 + 25 * k, accel=(k, 0, 9.8), gyro=(0, 0, k),
                             extra=extra) for k in range(5)]
    assert len(frames[0]) > 4 + 128 + 1
    listening = make_parser("xsens")
    samples = listening.feed(b"".join(frames))
    assert [s.accel[0] for s in samples] == [0, 1, 2, 3, 4] and listening.counts.oversized_headers == 0
    configured = make_parser("xsens", configure=True)
    assert configured.feed(b"".join(frames)) == [] and configured.counts.oversized_headers == 5


def test_sample_time_fine_and_counter_unwrap_across_wraparound() -> None:
    stf0, c0 = 2**32 - 60, 65530
    p = XsensParser()
    out = p.feed(b"".join(frame(k, stf0=stf0, counter0=c0) for k in range(10)))
    t = np.array([s.t_dev_ns for s in out])
    assert t[0] == stf0 * 100_000 and np.all(np.diff(t) == 2_500_000)
    assert [s.seq for s in out] == list(range(c0, c0 + 10))
    assert p.counts.seq_gaps == 0


def test_float64_precision_and_malformed_and_nonfinite() -> None:
    p = XsensParser()
    f64 = encode_mtdata2(counter=1, sample_time_fine=10, accel=(0.1, 0.2, 9.80665), gyro=(1e-3, 2e-3, 3e-3),
                         precision="f64")
    bad_size = encode_frame(0x36, struct.pack(">HB", 0x4020, 8) + bytes(8))   # accel of 8 bytes
    overrun = encode_frame(0x36, struct.pack(">HB", 0x1020, 9) + bytes(2))    # field runs off the end
    nan = encode_mtdata2(counter=2, sample_time_fine=35, accel=(float("nan"), 0, 0), gyro=(0, 0, 0))
    unknown = encode_mtdata2(extra=[(0x2030, bytes(16))])                     # quaternion only
    out = p.feed(f64 + bad_size + overrun + nan + unknown)
    assert len(out) == 1 and out[0].accel == (0.1, 0.2, 9.80665) and out[0].gyro == (1e-3, 2e-3, 3e-3)
    assert p.counts.malformed_packets == 2 and p.counts.nonfinite == 1 and p.counts.unknown_packets == 1
    assert decode_mtdata2(unknown[4:-1]) == {0x2030: bytes(16)}
    # the coordinate-frame bits (0x4024: NED) still match Acceleration
    ned = encode_frame(0x36, struct.pack(">HB", 0x1060, 4) + struct.pack(">I", 60)
                       + struct.pack(">HB", 0x4024, 12) + struct.pack(">3f", 1, 2, 3)
                       + struct.pack(">HB", 0x8024, 12) + struct.pack(">3f", 4, 5, 6))
    s = p.feed(ned)
    assert len(s) == 1 and s[0].accel == (1, 2, 3) and s[0].gyro == (4, 5, 6)


def test_encoder_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError):
        encode_mtdata2(accel=(1, 2, 3), precision="f16")
    with pytest.raises(ValueError):
        XsensParser(max_payload=0)
