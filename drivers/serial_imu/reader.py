"""`SerialImu`: a serial IMU read on its own thread, stamped on the host clock (notes/drivers.md §2-3).

One daemon thread only reads, stamps (`time.monotonic_ns()` right after `read()`), parses and
enqueues; the consumer takes samples with `get(timeout)`. The device time of each sample is mapped
onto the host monotonic clock by `DeviceClock` (online lower-envelope fit of offset and drift), so
`ImuSample.t_ns` is host `time.monotonic_ns()` nanoseconds, free of USB/OS jitter, late by a
constant minimum latency (~1 ms) that the camera-IMU time-offset calibration absorbs.

The queue holds about `queue_seconds` of samples (`queue_seconds * max_rate_hz`). It is meant to be
lossless: if the consumer falls that far behind, the oldest sample is dropped and counted
(`report()["overflow"]`, `take_overflow()`), and the reader never blocks.

Ports are opened with `serial.serial_for_url`, so `/dev/ttyUSB0`, a pty path or `loop://` work
alike (a pty ignores the baud rate). For an FTDI adapter, set its latency_timer to 1 ms
(`/sys/bus/usb-serial/devices/ttyUSB0/latency_timer`) for the best stamps.

Errors are `runtime.errors.DeviceError` with one line naming the port, with `.port` and `.reason`
attributes: `start()` raises "missing", "permission", "busy", "not_serial", "timeout", "open" or "stopped"
(after or during `stop()`);
the reader records "unplugged" (read failed: SerialException/OSError), "silent" (not one byte within
`first_byte_timeout_s` of the start: the device is off, not streaming, or on another port), "stall" (no
valid sample for `stall_timeout_s` after samples had been flowing), "no_valid_data" (bytes arriving
but not one valid sample within the longer of `stall_timeout_s` and `first_byte_timeout_s` of the
start: wrong protocol, baud rate or output configuration) or "reader" (an unexpected failure) in
`.error`, and `get()` raises it once the queue is drained.
"""
from __future__ import annotations

import errno
import os
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from drivers.serial_imu.clock import DeviceClock
from drivers.serial_imu.text import TextParser
from drivers.serial_imu.xsens import (
    DEFAULT_MAX_PAYLOAD,
    XBUS_MAX_PAYLOAD,
    XsensParser,
    go_to_config,
    go_to_measurement,
    set_output_configuration,
)
from runtime.errors import ConfigError, DeviceError
from runtime.events import ImuSample

PROTOCOLS: tuple[str, ...] = ("xsens", "text")
"""Protocol names accepted by `SerialImu(protocol=...)`."""

READ_TIMEOUT_S = 0.05
"""Serial read timeout: how long one read waits for the first byte (bounds `stop()` and stall checks)."""


def make_parser(protocol: str, configure: bool = False) -> XsensParser | TextParser:
    """The byte parser of a protocol name (see PROTOCOLS). An Xsens device the reader configures sends the
    four fields it asks for (DEFAULT_MAX_PAYLOAD); one it only listens to may send any frame
    (XBUS_MAX_PAYLOAD)."""
    if protocol == "xsens":
        return XsensParser(DEFAULT_MAX_PAYLOAD if configure else XBUS_MAX_PAYLOAD)
    if protocol == "text":
        return TextParser()
    raise ConfigError(f"unknown serial IMU protocol {protocol!r}; expected one of {', '.join(PROTOCOLS)}")


def device_error(port: str, reason: str, message: str) -> DeviceError:
    """A DeviceError with `.port` and `.reason` set."""
    err = DeviceError(message)
    err.port = port  # type: ignore[attr-defined]
    err.reason = reason  # type: ignore[attr-defined]
    return err


def open_error(port: str, exc: BaseException) -> DeviceError:
    """A one-line DeviceError explaining why `port` did not open, with the likely fix."""
    code = getattr(exc, "errno", None)
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    low = text.lower()
    if code == errno.ENOENT or "no such file" in low:
        return device_error(port, "missing", f"serial port {port} does not exist: is the IMU plugged in? "
                                             "(list the ports with `python -m serial.tools.list_ports`)")
    if code in (errno.EACCES, errno.EPERM) or "permission denied" in low:
        return device_error(port, "permission",
                            f"permission denied opening serial port {port}: add your user to the 'dialout' "
                            "group (sudo usermod -aG dialout $USER, then log in again) or fix its udev rule")
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK) or "could not exclusively lock" in low \
            or "resource busy" in low:
        return device_error(port, "busy", f"serial port {port} is busy: another program holds it (a serial "
                                          "monitor, another davio, ModemManager); close it and retry")
    if code in (errno.ENOTTY, errno.EINVAL) or "inappropriate ioctl" in low:
        return device_error(port, "not_serial", f"{port} is not a serial port ({text})")
    return device_error(port, "open", f"cannot open serial port {port}: {text}")


class SerialImu:
    """A serial IMU (Xsens MTData2 or the `$IMU` text protocol) read on a thread.

    Args:
        port: device path (/dev/ttyUSB0, /dev/ttyACM0, a pty) or a pyserial URL (loop://, ...).
        protocol: "xsens" (Xbus MTData2) or "text" (`$IMU,seq,t_dev_us,ax,ay,az,gx,gy,gz*HH`).
        baudrate: serial baud rate (400 Hz MTData2 with counter, time, accel, gyro needs >= 230400).
        stall_timeout_s: no valid sample for this long, after samples were flowing, is an error.
        queue_seconds: the queue holds `queue_seconds * max_rate_hz` samples.
        max_rate_hz: the highest sample rate expected (sizes the queue).
        configure: send GoToConfig, SetOutputConfiguration (counter, SampleTimeFine, accel, gyro at
            `output_rate_hz`) and GoToMeasurement on start (Xsens only). The bytes received before the
            device is in its configuration state (messages of its former output configuration) are
            discarded and counted (`configure_discarded_bytes`). Default: only listen.
        output_rate_hz: the rate requested when configuring.
        open_timeout_s: `start()` gives up opening the port after this long.
        first_byte_timeout_s: not one byte within this long after the start is an error ("silent").
            10 s: microcontroller IMUs reset when the port opens (a bootloader for 1-2 s) and often
            calibrate their gyroscope at rest before they stream.
        clock: the DeviceClock to use (default: DeviceClock()).
    """

    def __init__(self, port: str, protocol: str = "xsens", baudrate: int = 460800,
                 stall_timeout_s: float = 1.0, queue_seconds: float = 5.0, *,
                 max_rate_hz: float = 1000.0, configure: bool = False, output_rate_hz: int = 400,
                 open_timeout_s: float = 2.0, first_byte_timeout_s: float = 10.0,
                 clock: DeviceClock | None = None) -> None:
        if protocol not in PROTOCOLS:
            raise ConfigError(f"unknown serial IMU protocol {protocol!r}; expected one of "
                              f"{', '.join(PROTOCOLS)}")
        if not port:
            raise ConfigError("serial IMU port is empty (e.g. /dev/ttyUSB0)")
        if baudrate <= 0 or stall_timeout_s <= 0 or queue_seconds <= 0 or max_rate_hz <= 0 \
                or not first_byte_timeout_s > 0:
            raise ConfigError("serial IMU: baudrate, stall_timeout_s, queue_seconds, max_rate_hz and "
                              "first_byte_timeout_s must be > 0")
        if configure and protocol != "xsens":
            raise ConfigError("serial IMU: configure=True is only supported for the xsens protocol")
        self.port = str(port)
        self.protocol = protocol
        self.baudrate = int(baudrate)
        self.stall_timeout_s = float(stall_timeout_s)
        self.queue_seconds = float(queue_seconds)
        self.capacity = max(1, int(round(queue_seconds * max_rate_hz)))
        self.configure = bool(configure)
        self.configure_discarded_bytes = 0
        self.output_rate_hz = int(output_rate_hz)
        self.open_timeout_s = float(open_timeout_s)
        self.first_byte_timeout_s = float(first_byte_timeout_s)
        self.parser = make_parser(protocol, configure)
        self.clock = clock if clock is not None else DeviceClock()
        self.error: DeviceError | None = None
        """the failure recorded by the reader thread (raised by `get` once the queue is drained)"""
        self._ser: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._queue: deque[ImuSample] = deque()
        self._started = False
        self._stopped = False
        self._running = False
        self.enqueued = 0
        self.delivered = 0
        self.overflow = 0
        self._overflow_pending = 0
        self.bytes_read = 0
        self.reads = 0
        self._first_byte_ns: int | None = None
        self._last_valid_ns: int | None = None
        self._reading_since_ns = 0

    # --- lifecycle -----------------------------------------------------------------------------
    def start(self) -> SerialImu:
        """Open the port and start the reader thread; raises DeviceError (one line) if it does not open, or
        ("stopped") after or during `stop()` (from another thread or a signal handler: nothing would close
        the port again). Idempotent."""
        if self._started:
            return self
        if self._stopped:
            raise device_error(self.port, "stopped", f"serial port {self.port}: start() after stop()")
        self._ser = self._open()
        self._started = True
        self._stopped_while_starting()
        if self.configure:
            try:
                self.send(go_to_config())
                time.sleep(0.05)
                # what came before GoToConfig took effect is in the former configuration's format
                self.configure_discarded_bytes = self._discard_input()
                for cmd in (set_output_configuration(self.output_rate_hz), go_to_measurement()):
                    self.send(cmd)
                    time.sleep(0.05)
            except DeviceError:
                self.stop()
                raise
        self._stopped_while_starting()
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"serial-imu {self.port}", daemon=True)
        self._thread.start()
        return self

    def _stopped_while_starting(self) -> None:
        """A `stop()` that came while the port opened (it may not have seen the port yet) closes it here."""
        if not self._stopped:
            return
        try:
            self._ser.close()
        except Exception:  # noqa: BLE001 - closing a dead port may fail; nothing to do
            pass
        raise device_error(self.port, "stopped", f"serial port {self.port}: stopped while it opened")

    def _open(self) -> Any:
        try:
            import serial  # lazily: only live use needs pyserial
        except ImportError:
            raise device_error(self.port, "open", "reading a serial IMU needs pyserial: pip install "
                                                  "pyserial") from None

        result: dict[str, Any] = {}
        kwargs: dict[str, Any] = {"baudrate": self.baudrate, "timeout": READ_TIMEOUT_S}
        if os.name == "posix" and "://" not in self.port:
            kwargs["exclusive"] = True

        def target() -> None:
            try:
                result["ser"] = serial.serial_for_url(self.port, **kwargs)
            except BaseException as exc:  # noqa: BLE001 - reported to the caller below
                result["exc"] = exc

        opener = threading.Thread(target=target, name=f"open {self.port}", daemon=True)
        opener.start()
        opener.join(self.open_timeout_s)
        if opener.is_alive():
            def reap() -> None:  # close the port if the open finishes after all
                opener.join()
                if result.get("ser") is not None:
                    result["ser"].close()

            threading.Thread(target=reap, daemon=True).start()
            raise device_error(self.port, "timeout",
                               f"opening serial port {self.port} did not finish within "
                               f"{self.open_timeout_s:g} s: check the device and its driver")
        if "exc" in result:
            raise open_error(self.port, result["exc"]) from None
        return result["ser"]

    def send(self, data: bytes) -> None:
        """Write bytes to the device (configuration commands); raises DeviceError on failure."""
        if self._ser is None:
            raise device_error(self.port, "not_started", f"serial IMU {self.port}: send() before start()")
        try:
            self._ser.write(bytes(data))
            self._ser.flush()
        except Exception as exc:  # noqa: BLE001 - pyserial raises SerialException/OSError/others
            raise device_error(self.port, "unplugged",
                               f"writing to serial port {self.port} failed: {exc}") from None

    def _discard_input(self) -> int:
        """Read and drop what the port has received so far; returns how many bytes that was (read, not
        reset: what arrives meanwhile is either counted here or parsed later, never lost uncounted)."""
        try:
            waiting = int(getattr(self._ser, "in_waiting", 0) or 0)
            dropped = len(self._ser.read(waiting)) if waiting > 0 else 0
        except Exception as exc:  # noqa: BLE001 - pyserial raises SerialException/OSError/others
            raise device_error(self.port, "unplugged",
                               f"reading serial port {self.port} failed: {exc}") from None
        return dropped

    def stop(self) -> None:
        """Stop the reader, join it and close the port (idempotent). Buffered samples stay readable."""
        if self._stopped:
            return
        self._stopped = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port may fail; nothing to do
                pass
        with self._cond:
            self._running = False
            self._cond.notify_all()

    close = stop

    def __enter__(self) -> SerialImu:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # --- reader thread -------------------------------------------------------------------------
    def _run(self) -> None:
        import serial

        ser = self._ser
        self._reading_since_ns = time.monotonic_ns()
        try:
            while not self._stop.is_set():
                try:
                    data = ser.read(1)
                    if data:
                        n = ser.in_waiting
                        if n:
                            data += ser.read(n)
                except (serial.SerialException, OSError) as exc:
                    if not self._stop.is_set():
                        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                        self._fail("unplugged", f"serial IMU {self.port}: the device was unplugged or the "
                                                f"port closed (read failed: {first})")
                    break
                t_host = time.monotonic_ns()
                if data:
                    self._ingest(bytes(data), t_host)
                if self._stalled(t_host):
                    break
        except Exception as exc:  # noqa: BLE001 - never a traceback from the thread
            self._fail("reader", f"serial IMU {self.port}: reader failed: {type(exc).__name__}: {exc}")
        finally:
            try:
                self.parser.finish()
            except Exception:  # noqa: BLE001
                pass
            with self._cond:
                self._running = False
                self._cond.notify_all()

    def _ingest(self, data: bytes, t_host: int) -> None:
        self.reads += 1
        self.bytes_read += len(data)
        if self._first_byte_ns is None:
            self._first_byte_ns = t_host
        samples = self.parser.feed(data)
        if not samples:
            return
        self._last_valid_ns = t_host
        stamps = [self.clock.update(s.t_dev_ns, t_host) for s in samples]     # None: dropped (counted)
        events = [ImuSample(t, np.array(s.gyro, dtype=np.float64), np.array(s.accel, dtype=np.float64))
                  for t, s in zip(stamps, samples, strict=True) if t is not None]
        with self._cond:
            for ev in events:
                if len(self._queue) >= self.capacity:
                    self._queue.popleft()
                    self.overflow += 1
                    self._overflow_pending += 1
                self._queue.append(ev)
            self.enqueued += len(events)
            self._cond.notify_all()

    def _stalled(self, t_host: int) -> bool:
        limit = int(self.stall_timeout_s * 1e9)
        if self._last_valid_ns is not None:
            if t_host - self._last_valid_ns > limit:
                self._fail("stall", f"serial IMU {self.port}: no valid sample for {self.stall_timeout_s:g} s "
                                    f"after {self.enqueued} samples: the device stopped sending or the link "
                                    f"is corrupt ({self._counter_text()})")
                return True
        elif self._first_byte_ns is None:
            if t_host - self._reading_since_ns > int(self.first_byte_timeout_s * 1e9):
                how = "its output"
                if self.protocol == "xsens":
                    how = ("its output configuration (MTData2 with acceleration, rate of turn and a sample "
                           "time; SerialImu(configure=True) sets it)")
                self._fail("silent", f"serial IMU {self.port}: not one byte in "
                                     f"{self.first_byte_timeout_s:g} s since the port opened: is the IMU "
                                     f"powered, streaming and on this port? (baud rate {self.baudrate}; "
                                     f"check {how})")
                return True
        elif t_host - self._reading_since_ns > (wait := max(limit, int(self.first_byte_timeout_s * 1e9))):
            # bytes but no valid sample yet: a device may print a banner, then calibrate, before streaming
            lacking = getattr(self.parser, "last_missing", None)
            fix = "make the firmware print all nine fields of each $IMU line"
            if self.protocol == "xsens":
                fix = "configure the device's outputs (SerialImu(configure=True) does for an Xsens)"
            hint = (f"packets lack {lacking}; {fix}" if lacking
                    else f"check the protocol ({self.protocol}) and the baud rate ({self.baudrate})")
            self._fail("no_valid_data",
                       f"serial IMU {self.port}: {self.bytes_read} bytes in {wait * 1e-9:g} s since the port "
                       f"opened but no valid {self.protocol} sample: {hint} ({self._counter_text()})")
            return True
        return False

    def _counter_text(self) -> str:
        c = self.parser.counts
        return (f"checksum errors {c.checksum_errors}, bytes skipped {c.bytes_skipped}, "
                f"missing fields {c.missing_fields}, malformed {c.malformed_packets}")

    def _fail(self, reason: str, message: str) -> None:
        with self._cond:
            if self.error is None:
                self.error = device_error(self.port, reason, message)
            self._cond.notify_all()

    # --- consumer ------------------------------------------------------------------------------
    def get(self, timeout: float | None) -> ImuSample | None:
        """The next sample (host-clock int64 ns stamp, gyro rad/s, accel m/s^2, float64 arrays).

        Returns None when nothing arrives within `timeout` s (None: wait until a sample, an error or
        `stop()`), or when stopped and drained. Raises the reader's DeviceError once the queue is
        drained (and on every later call).
        """
        if not self._started:
            raise device_error(self.port, "not_started", f"serial IMU {self.port}: get() before start()")
        deadline = None if timeout is None else time.monotonic() + max(0.0, float(timeout))
        with self._cond:
            while not self._queue:
                if self.error is not None:
                    raise self.error.with_traceback(None)
                if not self._running:
                    return None
                if deadline is None:
                    self._cond.wait(0.25)
                    continue
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)
            self.delivered += 1
            return self._queue.popleft()

    def take_overflow(self) -> int:
        """Samples dropped by overflow since the last call (non-zero: reset IMU preintegration)."""
        with self._cond:
            n, self._overflow_pending = self._overflow_pending, 0
            return n

    @property
    def running(self) -> bool:
        """True while the reader thread runs."""
        return self._running

    def queued(self) -> int:
        """Samples waiting in the queue."""
        return len(self._queue)

    def report(self) -> dict:
        """JSON-ready counters: intake, parser, queue and clock fit."""
        c = self.parser.counts
        out: dict[str, Any] = {
            "driver": "serial_imu", "port": self.port, "protocol": self.protocol, "baudrate": self.baudrate,
            "samples": self.enqueued, "delivered": self.delivered, "queued": len(self._queue),
            "queue_capacity": self.capacity, "overflow": self.overflow,
            "bytes_read": self.bytes_read, "reads": self.reads,
            "checksum_errors": c.checksum_errors, "bytes_skipped": c.bytes_skipped,
            "partial_packets": c.partial_packets, "oversized_headers": c.oversized_headers,
            "unknown_packets": c.unknown_packets, "missing_fields": c.missing_fields,
            "malformed_packets": c.malformed_packets, "nonfinite": c.nonfinite,
            "seq_gaps": c.seq_gaps, "missing_estimated": c.missing_estimated,
            "configure_discarded_bytes": self.configure_discarded_bytes,
        }
        out.update(self.clock.report())
        out["error"] = None if self.error is None else str(self.error)
        out["error_reason"] = None if self.error is None else getattr(self.error, "reason", None)
        return out
