"""The `$IMU` ASCII protocol: checksum, resynchronisation, exact counters, 32-bit time wrap."""
from __future__ import annotations

import random

import numpy as np

from drivers.serial_imu.text import TextParser, encode_line, nmea_checksum


def values(k: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    return (0.5 * k, -1.25, 9.81), (k / 64.0, -0.003, 0.125)


def line(k: int, t0_us: int = 1000) -> bytes:
    acc, gyr = values(k)
    return encode_line(k, t0_us + 2500 * k, acc, gyr)


def with_checksum(body: str) -> bytes:
    return f"${body}*{nmea_checksum(body):02X}\r\n".encode()


def feed_chunked(p: TextParser, data: bytes, seed: int = 0) -> list:
    rng = random.Random(seed)
    out, i = [], 0
    while i < len(data):
        n = rng.randint(1, 13)
        out += p.feed(data[i:i + n])
        i += n
    return out


def test_nmea_checksum_of_a_published_sentence_and_the_encoder() -> None:
    # the classic NMEA example sentence and its published checksum 0x47
    assert nmea_checksum("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,") == 0x47
    body = "IMU,1,2500,0.1,0.2,9.81,0.01,-0.02,0.03"
    assert encode_line(1, 2500, (0.1, 0.2, 9.81), (0.01, -0.02, 0.03)) == with_checksum(body)
    s = TextParser().feed(with_checksum(body))[0]
    assert s.seq == 1 and s.t_dev_ns == 2_500_000
    assert s.accel == (0.1, 0.2, 9.81) and s.gyro == (0.01, -0.02, 0.03)


def test_garbage_corrupt_and_other_sentences_are_counted_exactly() -> None:
    lines = [line(k) for k in range(30)]
    corrupt = bytearray(lines[7])
    corrupt[10] = ord("9") if corrupt[10] != ord("9") else ord("8")          # a digit changed
    garbage = b"\x00\xffnoise\r\n"                                             # 9 bytes, no '$'
    no_star = b"$IMU,1,2,3,4,5,6,7,8\r\n"                                     # no checksum: untrusted
    too_long = b"$" + b"A" * 300 + b"\r\n"                                     # longer than max_line
    cut = b"$IMU,99,12"                                                        # cut by the next '$'
    gga = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
    short = with_checksum("IMU,5,100,1,2,3")                                  # missing fields
    extra = with_checksum("IMU,5,100,1,2,3,4,5,6,7")                          # one field too many
    bad_num = with_checksum("IMU,5,100,1,x,3,4,5,6")
    inf = with_checksum("IMU,5,100,1,inf,3,4,5,6")
    bare_lf = lines[20].replace(b"\r\n", b"\n")
    partial = lines[29][:15]
    stream = (garbage + b"".join(lines[:5]) + no_star + b"".join(lines[5:7]) + bytes(corrupt)
              + b"".join(lines[8:12]) + too_long + cut + b"".join(lines[12:15]) + gga + short + extra
              + bad_num + inf + b"".join(lines[15:20]) + bare_lf + b"".join(lines[21:29]) + partial)
    for chunked in (False, True):
        p = TextParser()
        out = feed_chunked(p, stream, seed=5) if chunked else p.feed(stream)
        p.finish()
        c = p.counts
        kept = [k for k in range(29) if k != 7]
        assert [s.seq for s in out] == kept
        for s, k in zip(out, kept, strict=True):
            acc, gyr = values(k)
            assert s.accel == acc and s.gyro == gyr and s.t_dev_ns == (1000 + 2500 * k) * 1000
        assert c.samples == 28 and c.checksum_errors == 2 and c.oversized_headers == 1
        assert c.unknown_packets == 1 and c.missing_fields == 1 and c.malformed_packets == 2
        assert c.nonfinite == 1 and c.partial_packets == 1 and c.frames == 28 + 5
        assert c.bytes_skipped == (len(garbage) + len(no_star) + len(corrupt) + len(too_long) + len(cut)
                                   + len(partial))
        assert c.bytes_in == len(stream) == c.bytes_framed + c.bytes_skipped
        assert c.seq_gaps == 1 and c.missing_estimated == 1   # seq 7 lost (the invalid seq-5 lines gave none)


def test_device_microseconds_unwrap_across_32_bits() -> None:
    t0 = 2**32 - 6000
    p = TextParser()
    out = p.feed(b"".join(line(k, t0_us=t0) for k in range(6)))
    t = np.array([s.t_dev_ns for s in out])
    assert t[0] == t0 * 1000 and np.all(np.diff(t) == 2_500_000)


def test_cr_only_and_crlf_split_across_reads_lose_nothing() -> None:
    """A device ending its lines in CR alone delivered nothing: each line was cut by the next '$'."""
    cr_only = b"".join(line(k).replace(b"\r\n", b"\r") for k in range(50))
    for seed in range(3):
        p = TextParser()
        out = feed_chunked(p, cr_only, seed)
        assert [s.seq for s in out] == list(range(50)) and p.counts.bytes_skipped == 0
    p = TextParser()                                    # CRLF cut between CR and LF at every line
    out = []
    for k in range(20):
        raw = line(k)
        out += p.feed(raw[:-1]) + p.feed(raw[-1:])
    assert len(out) == 20 and p.counts.bytes_skipped == 0
    assert p.counts.bytes_in == p.counts.bytes_framed + p.counts.bytes_skipped + p.pending


def test_digit_groups_and_a_repeated_line_are_dropped_and_counted() -> None:
    p = TextParser()
    out = p.feed(line(0) + with_checksum("IMU,1,1_0,0,0,9.81,0,0,0") + line(1) + line(1) + line(2))
    assert [s.seq for s in out] == [0, 1, 2]             # the repeat was stamped 1 ns later
    assert (p.counts.malformed_packets, p.counts.duplicates, p.counts.seq_gaps) == (1, 1, 0)
