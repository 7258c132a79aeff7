"""SerialImu end to end, no hardware: a pty (os.openpty) and pyserial's loop:// stand in for the device."""
from __future__ import annotations

import errno
import json
import os
import threading
import time
import tty

import numpy as np
import pytest

from drivers.serial_imu import PROTOCOLS, SerialImu
from drivers.serial_imu.reader import open_error
from drivers.serial_imu.text import encode_line
from drivers.serial_imu.xsens import encode_mtdata2, go_to_config, go_to_measurement, set_output_configuration
from runtime.errors import ConfigError, DeviceError
from runtime.events import ImuSample

REPORT_KEYS = {"samples", "checksum_errors", "bytes_skipped", "partial_packets", "overflow", "clock_jumps",
               "drift_ppm", "fit_residual_ns", "offset_ns", "error"}


def values(k: int) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    return (0.5 * k, -1.25, 9.75), (k / 64.0, -k / 128.0, 0.125)


def xsens_frame(k: int) -> bytes:
    acc, gyr = values(k)
    return encode_mtdata2(counter=k, sample_time_fine=5000 + 25 * k, accel=acc, gyro=gyr)


class Pty:
    """A pty pair: the test writes to `master`, the driver opens `path` (the slave)."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.master_open = True

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def close_master(self) -> None:
        if self.master_open:
            os.close(self.master)
            self.master_open = False

    def close(self) -> None:
        self.close_master()
        os.close(self.slave)


@pytest.fixture
def pty_pair():
    p = Pty()
    yield p
    p.close()


def collect(imu: SerialImu, n: int, timeout_s: float = 5.0) -> list[ImuSample]:
    out: list[ImuSample] = []
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        s = imu.get(timeout=0.1)
        if s is not None:
            out.append(s)
    return out


def wait_error(imu: SerialImu, timeout_s: float = 10.0) -> DeviceError:
    """The DeviceError get() raises; `timeout_s` only keeps a broken reader from hanging the test (which
    error it is, its reason, tells how the reader ended)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        try:
            imu.get(timeout=0.05)
        except DeviceError as exc:
            return exc
    raise AssertionError(f"no DeviceError within {timeout_s} s")


def test_pty_400hz_stream_then_unplug(pty_pair: Pty) -> None:
    n = 400
    imu = SerialImu(pty_pair.path, protocol="xsens", stall_timeout_s=1.0)
    with imu:
        t_start = time.monotonic_ns()

        def writer() -> None:  # 400 Hz for 1 s, 4 frames every 10 ms
            t0 = time.monotonic()
            for b in range(n // 4):
                pty_pair.write(b"".join(xsens_frame(k) for k in range(4 * b, 4 * b + 4)))
                time.sleep(max(0.0, t0 + (b + 1) * 0.01 - time.monotonic()))

        th = threading.Thread(target=writer, daemon=True)
        th.start()
        got = collect(imu, n, timeout_s=6.0)
        th.join(5.0)
        t_end = time.monotonic_ns()
        assert len(got) == n
        for k, s in enumerate(got):
            acc, gyr = values(k)
            assert s.gyro.dtype == np.float64 and s.accel.dtype == np.float64
            np.testing.assert_array_equal(s.accel, acc)
            np.testing.assert_array_equal(s.gyro, gyr)
        t = np.array([s.t_ns for s in got], dtype=np.int64)
        assert np.all(np.diff(t) > 0)
        assert t_start - 50_000_000 < t[0] and t[-1] < t_end        # host monotonic clock
        # stamps follow the device's 2.5 ms spacing, not the 10 ms write bursts
        assert abs(np.median(np.diff(t)) - 2_500_000) < 100_000
        rep = imu.report()
        assert rep["samples"] == n and rep["checksum_errors"] == 0 and rep["bytes_skipped"] == 0
        assert rep["overflow"] == 0 and rep["seq_gaps"] == 0 and REPORT_KEYS <= set(rep)
        json.dumps(rep)
        # unplug: the master end goes away -> DeviceError within ~1 s, no hang, no thread traceback
        pty_pair.write(xsens_frame(n)[:10])
        time.sleep(0.1)
        pty_pair.close_master()
        err = wait_error(imu)
        assert err.reason == "unplugged" and pty_pair.path in str(err)
        assert "\n" not in str(err)
        with pytest.raises(DeviceError):
            imu.get(timeout=0.01)              # and again: the error stays
    assert not imu.running
    rep = imu.report()
    assert rep["error_reason"] == "unplugged" and rep["partial_packets"] == 1
    imu.stop()                                 # idempotent


def test_stall_after_flowing_is_a_device_error(pty_pair: Pty) -> None:
    imu = SerialImu(pty_pair.path, protocol="text", stall_timeout_s=0.3)
    with imu:
        pty_pair.write(b"".join(encode_line(k, 1000 + 2500 * k, *values(k)) for k in range(20)))
        assert len(collect(imu, 20, 3.0)) == 20
        err = wait_error(imu)       # the master stays open, nothing more comes
        assert err.reason == "stall" and "0.3 s" in str(err)


def test_a_port_that_never_sends_a_byte_is_a_device_error(pty_pair: Pty) -> None:
    """Opened, never written to: a live run must not wait forever for its first sample."""
    imu = SerialImu(pty_pair.path, protocol="text", baudrate=115200, first_byte_timeout_s=0.4)
    with imu:
        err = wait_error(imu)
        assert err.reason == "silent" and "not one byte in 0.4 s" in str(err) and "115200" in str(err)
        with pytest.raises(DeviceError, match="not one byte"):
            imu.get(0.1)
    late = SerialImu(pty_pair.path, protocol="text", first_byte_timeout_s=0.4)
    with late:   # a first byte within the limit: no error, whatever comes later is judged as before
        pty_pair.write(b"".join(encode_line(k, 1000 + 2500 * k, *values(k)) for k in range(5)))
        assert len(collect(late, 5, 3.0)) == 5 and late.error is None


def test_a_banner_then_samples_within_the_first_byte_allowance_is_no_error(pty_pair: Pty) -> None:
    """A microcontroller IMU prints a banner, calibrates, then streams: bytes without a valid sample are
    an error only after the longer of stall_timeout_s and first_byte_timeout_s from the start."""
    imu = SerialImu(pty_pair.path, protocol="text", stall_timeout_s=0.2, first_byte_timeout_s=1.5)
    with imu:
        pty_pair.write(b"MPU6050 ready, calibrating gyro, keep still...\r\n")
        time.sleep(0.8)                            # beyond stall_timeout_s, within the allowance
        assert imu.error is None
        pty_pair.write(b"".join(encode_line(k, 1000 + 2500 * k, *values(k)) for k in range(5)))
        assert len(collect(imu, 5, 3.0)) == 5 and imu.error is None


def test_bytes_without_valid_samples_name_protocol_and_baud(pty_pair: Pty) -> None:
    imu = SerialImu(pty_pair.path, protocol="xsens", baudrate=115200, stall_timeout_s=0.3,
                    first_byte_timeout_s=0.3)
    with imu:
        t0 = time.monotonic()
        while imu.error is None and time.monotonic() - t0 < 3.0:
            pty_pair.write(b"$IMU,1,2,3\r\n" * 4)   # text, but the driver expects Xsens
            time.sleep(0.02)
        err = wait_error(imu)
        assert err.reason == "no_valid_data" and "xsens" in str(err) and "115200" in str(err)


def test_missing_busy_and_bad_ports_fail_fast_with_one_line(pty_pair: Pty) -> None:
    imu = SerialImu("/dev/ttyDAVIO_does_not_exist")
    with pytest.raises(DeviceError) as ei:
        imu.start()
    msg = str(ei.value)
    assert ei.value.reason == "missing" and "/dev/ttyDAVIO_does_not_exist" in msg and "plugged" in msg
    assert "\n" not in msg
    with SerialImu(pty_pair.path):
        with pytest.raises(DeviceError) as ei:
            SerialImu(pty_pair.path).start()
        assert ei.value.reason == "busy" and pty_pair.path in str(ei.value)
    clock = open_error("/dev/clock_imu", IsADirectoryError(errno.EISDIR, "Is a directory", "/dev/clock_imu"))
    assert clock.reason == "open" and "Is a directory" in str(clock)     # "clock" is no lock: not "busy"
    perm = open_error("/dev/ttyUSB0", PermissionError(errno.EACCES, "Permission denied"))
    assert perm.reason == "permission" and "dialout" in str(perm) and "/dev/ttyUSB0" in str(perm)
    with pytest.raises(DeviceError) as ei:
        SerialImu("/dev/null").start()
    assert ei.value.reason == "not_serial"
    with pytest.raises(ConfigError):
        SerialImu("loop://", protocol="nmea")
    with pytest.raises(ConfigError):
        SerialImu("loop://", protocol="text", configure=True)
    with pytest.raises(DeviceError):
        SerialImu("loop://").get(0.01)           # before start
    stopped = SerialImu(pty_pair.path)
    stopped.stop()      # a stop first (e.g. from another thread while LiveDriver starts its sources)
    with pytest.raises(DeviceError, match=r"start\(\) after stop\(\)") as ei:
        stopped.start()                          # would open a port that nothing closes
    assert ei.value.reason == "stopped"
    with SerialImu(pty_pair.path):               # the port was not opened: free
        pass


def test_a_stop_while_the_port_opens_closes_it(pty_pair: Pty, monkeypatch) -> None:
    """stop() from another thread while start() waits for the port to open finds no port to close: start()
    closes it once opened, and says why it did not start."""
    opened = []
    real_open = SerialImu._open

    def open_then_stopped(self):
        port = real_open(self)
        opened.append(port)
        self.stop()                              # the other thread's stop, before start() took the port
        return port

    monkeypatch.setattr(SerialImu, "_open", open_then_stopped)
    with pytest.raises(DeviceError, match="stopped while it opened") as ei:
        SerialImu(pty_pair.path).start()
    assert ei.value.reason == "stopped" and not opened[0].is_open
    monkeypatch.undo()
    with SerialImu(pty_pair.path):               # free again
        pass
    assert PROTOCOLS == ("xsens", "text")


def test_loop_url_text_protocol_and_overflow() -> None:
    imu = SerialImu("loop://", protocol="text", queue_seconds=0.01, max_rate_hz=1000.0)   # 10 samples
    with imu:
        imu.send(b"".join(encode_line(k, 2500 * k, *values(k)) for k in range(50)))
        t0 = time.monotonic()
        while imu.report()["samples"] < 50 and time.monotonic() - t0 < 3.0:
            time.sleep(0.01)
        rep = imu.report()
        assert rep["samples"] == 50 and rep["overflow"] == 40 and rep["queue_capacity"] == 10
        assert imu.take_overflow() == 40 and imu.take_overflow() == 0
        got = collect(imu, 10, 2.0)
        assert [int(s.accel[0] * 2) for s in got] == list(range(40, 50))   # the newest 10 are kept
    assert imu.get(timeout=0.01) is None and imu.get(None) is None   # stopped and drained


def test_configure_sends_the_xsens_commands_only_when_asked() -> None:
    imu = SerialImu("loop://", protocol="xsens", configure=True)
    with imu:
        time.sleep(0.2)
        rep = imu.report()
        # loop:// echoes what was sent. What arrived before GoToConfig took effect is discarded (a device's
        # packets in its former output configuration; here GoToConfig's own echo): the two later commands
        # come back as two valid non-MTData2 frames
        expected = len(set_output_configuration(400)) + len(go_to_measurement())
        assert rep["bytes_read"] == expected and rep["unknown_packets"] == 2 and rep["samples"] == 0
        assert rep["configure_discarded_bytes"] == len(go_to_config())
    quiet = SerialImu("loop://", protocol="xsens")
    with quiet:
        time.sleep(0.1)
        assert quiet.report()["bytes_read"] == 0
