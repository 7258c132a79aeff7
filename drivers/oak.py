"""Luxonis OAK (depthai 3): one camera socket and the on-board IMU, read on threads (notes/drivers.md §1).

`OakDevice` opens one depthai pipeline (`drivers.oak_pipeline.build_pipeline`: a `Camera` node with one
GRAY8 output at the requested size and rate, an `IMU` node with ACCELEROMETER_UNCALIBRATED +
GYROSCOPE_UNCALIBRATED at one rate (`imu_calibrated`: the _CALIBRATED streams), batch threshold 1, at most
10 reports a batch; both host queues non-blocking and bounded) and exposes two sources for `LiveDriver`:

- `device.camera` (`OakCamera`): `Frame`s, grey (H, W) uint8 of the requested size. Each is stamped
  with `getTimestampDevice(dai.CameraExposureOffset.MIDDLE)`: the DEVICE clock at mid-exposure, int64
  ns (depthai hands it over as a timedelta, so with microsecond resolution). Keeps the newest
  `keep_frames` frames, counts the older ones it drops (`dropped_old`), the frames the device skipped
  (`seq_gaps`, from the sequence numbers) and stamps that did not increase (`nonmonotonic`, dropped).
  The colour socket (CAM_A) is requested as NV12 and its luma plane is the grey image (`converted`).
- `device.imu` (`OakImu`): every report of every packet of every batch, as `ImuSample`s on the same
  device clock (the reports' `tsDevice`, ns). Accelerometer and gyroscope reports are paired by stamp:
  a sample is emitted at each gyroscope stamp, with the accelerometer taken at that stamp (linearly
  interpolated between the two accelerometer reports around it when the stamps differ). A report that
  repeats or precedes its stream's previous stamp is dropped and counted. The queue is meant to be
  lossless; on overflow the oldest sample goes and is counted (`overflow`, `take_overflow()`). Batches the
  device's own non-blocking queue dropped before the host read them show as a gyroscope stamp step of more
  than 1.5 periods (the median of the steps seen): the samples missing are counted (`gaps`,
  `lost_before_host`) and set on the next sample's `lost_before`. The report gives the rate measured from
  those steps (`rate_hz_measured`) and notes it when it is more than 10 % from the rate requested.
  The samples are in the DepthAI IMU frame, the frame `getImuToCameraExtrinsics` relates to the camera:
  since depthai 3's firmware the _RAW streams are the chip's native axes instead (their docstring), so
  they are not used.

Camera and IMU share the device clock, so LiveDriver merges them without any clock mapping; the Rig's
time offset is 0 (`read_oak_rig`). The reader threads only read, convert and enqueue.

Errors are `runtime.errors.DeviceError`, one line: `open()` / `start()` raise "no OAK device found (...)"
within `probe_timeout_s` (2 s) when none is attached (probe: `dai.Device.getAllAvailableDevices()`), or
why the device or the pipeline could not be opened. A queue that fails while running (the device was
unplugged or crashed: depthai closes the queues and raises `MessageQueue.QueueException`), that stays
silent for `stall_timeout_s`, or whose messages give nothing usable for that long (stamps that went back,
an accelerometer that stopped: the reason is counted in the error) sets `.error` on both sources; `get`
raises it once the samples already buffered have been taken. `stop()` is idempotent. Reconnection is off
(`setMaxReconnectionAttempts(0)`) and the pipeline stops on device loss (`setStopOnDeviceLoss(True)`):
depthai's default would reconnect a crashed device, whose clock then restarts near zero, so every stamp
after it would be dropped as going backwards while messages keep coming.

Calibration (`read_oak_rig`): intrinsics are the calibration's K at its own size, cropped and scaled to
the output size as the Camera node's ImgResizeMode.CROP does (`oak_calib.crop_intrinsics`; depthai's
`getCameraIntrinsics(socket, w, h)` pads instead for a 4:3 output of a 16:10 calibration). The first
frame's own intrinsics (`getTransformation().getIntrinsicMatrix()`) are kept in the camera's report
(`device_K`), and a difference of more than 1 % from the rig's K is noted there. Distortion
`Perspective` (OpenCV's 14 coefficients k1 k2 p1 p2 k3 k4 k5 k6 s1..s4 tx ty) becomes radtan (k1 k2 p1
p2[ k3]) when k4.. are zero, rational (k1..k6, `calib.PinholeRational`: many factory calibrations) when
only s1.. are, and is refused otherwise (thin-prism and tilt terms: pass a Kalibr calibration with --rig);
`Fisheye` becomes equidistant (k1..k4).

Extrinsics direction. `getImuToCameraExtrinsics(socket, False, dai.LengthUnit.METER)` (its default
unit is CENTIMETRES) returns the matrix that maps IMU coordinates to camera coordinates,
x_C = M x_I, i.e. T_CI in DESIGN §3's notation, so `T_IC = inverse(M)` (which is what
`getCameraToImuExtrinsics` returns). Evidence: depthai-core chains the stored links as
`getImuToCameraExtrinsics(cam) = getCameraExtrinsics(imu_link, cam) @ M_imu` and
`getCameraExtrinsics(src, dst) = inv(dst->origin) @ (src->origin)`, a composition that is only valid
when each stored matrix maps source coordinates into destination coordinates (tested on synthetic
calibrations in tests/drivers/test_oak.py: a rig of known geometry written in that convention reads
back as its T_IC through the chain); and the factory stereo link left->right of an OAK-D stores
t = (-7.5, 0, 0) cm, the left camera's centre in right-camera coordinates. Whether a given device's
IMU block was written in the same convention can be checked at rest with
`drivers.oak_calib.check_extrinsics_direction(rig.T_IC, mean_accel_I)` while the camera is held level
(image up = -y_C): the accelerometer reads +g along "up", so accel_I must be parallel to R_IC @ up_C.
The calibration reading itself lives in `drivers.oak_calib`, the probe and the pipeline factory in
`drivers.oak_pipeline`, the two sources in `drivers.oak_streams`.
"""
from __future__ import annotations

import datetime as _dt
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.oak_calib import read_oak_rig
from drivers.oak_pipeline import SOCKETS, OakPipeline, _one_line, build_pipeline
from drivers.oak_streams import (  # noqa: F401 - NEVER and timedelta_ns are public here too
    _POLL_S,
    NEVER,
    OakCamera,
    OakImu,
    timedelta_ns,
)
from runtime.errors import CalibrationError, DavioError, DeviceError

if TYPE_CHECKING:
    from calib import Rig


# -- the device ----------------------------------------------------------------------------------
class OakDevice:
    """An OAK camera socket and its IMU; `camera` and `imu` are the sources for `LiveDriver`. `open()` opens
    the device and reads its calibration (`rig()`) without starting the streams; `start()` (which the
    sources call) starts them.

    Args:
        socket: "CAM_B" (left mono, default), "CAM_C" (right mono) or "CAM_A" (colour; its luma).
        width, height, fps: the camera output (the Camera node crops to the aspect ratio and scales).
        imu_rate_hz: the rate requested for both accelerometer and gyroscope (the chip may round it).
        imu_calibrated: read the IMU streams corrected with the device's stored affine calibration
            (ACCELEROMETER/GYROSCOPE_CALIBRATED) instead of the uncorrected ones (_UNCALIBRATED, the
            default; the filter estimates the biases). Both are in the DepthAI IMU frame.
        device_id: the device's id (MxId) or name when several are attached; None: the first one.
        pipeline_factory: `factory(device) -> OakPipeline` (tests inject recorded queues); default
            `build_pipeline` (a real device).
        keep_frames: newest frames kept for the consumer; older ones are dropped and counted.
        imu_queue_seconds: the IMU sample queue holds this long at `imu_rate_hz` (x1.5).
        stall_timeout_s: a stream silent, or giving no usable frame or sample, this long after its first
            one is an error.
        first_message_timeout_s: a stream that delivers nothing this long after start is an error.
        probe_timeout_s: the device probe's limit (open() / start() fail within it when none is attached).
        camera_id: the `Frame.camera_id`.
    """

    def __init__(self, socket: str = "CAM_B", width: int = 640, height: int = 400, fps: float = 30.0,
                 imu_rate_hz: int = 200, device_id: str | None = None,
                 pipeline_factory: Callable[[OakDevice], OakPipeline] | None = None, *,
                 keep_frames: int = 2, imu_queue_seconds: float = 5.0, stall_timeout_s: float = 2.0,
                 first_message_timeout_s: float = 10.0, probe_timeout_s: float = 2.0,
                 camera_id: int = 0, imu_calibrated: bool = False) -> None:
        if socket not in SOCKETS:
            raise DeviceError(f"OAK socket must be one of {', '.join(SOCKETS)}, not {socket!r}")
        if int(width) <= 0 or int(height) <= 0:
            raise DeviceError(f"OAK image size must be positive, not {width}x{height}")
        if not fps > 0 or not imu_rate_hz >= 1:
            raise DeviceError(f"OAK fps must be > 0 and imu_rate_hz >= 1 (whole Hz), not {fps} and "
                              f"{imu_rate_hz}")
        if keep_frames < 1 or not imu_queue_seconds > 0 or not stall_timeout_s > 0:
            raise DeviceError("OAK keep_frames must be >= 1, imu_queue_seconds and stall_timeout_s > 0")
        self.socket = socket
        self.width, self.height = int(width), int(height)
        self.fps = float(fps)
        self.imu_rate_hz = int(imu_rate_hz)
        self.imu_calibrated = bool(imu_calibrated)
        self.device_id = device_id
        self.pipeline_factory = pipeline_factory or build_pipeline
        self.stall_timeout_s = float(stall_timeout_s)
        self.first_message_timeout_s = float(first_message_timeout_s)
        self.probe_timeout_s = float(probe_timeout_s)
        self.camera_queue_size = 4
        """Device-to-host queue of the camera (non-blocking: the oldest is overwritten)."""
        self.imu_queue_size = 50
        """Device-to-host queue of IMU batches (non-blocking)."""
        self.device = f"OAK {device_id}" if device_id else "OAK"
        self.camera = OakCamera(self, keep_frames=keep_frames, camera_id=camera_id)
        self.imu = OakImu(self, capacity=max(1, int(round(imu_queue_seconds * self.imu_rate_hz * 1.5))))
        self.pipe: OakPipeline | None = None
        self._lock = threading.Lock()
        self._started = False
        self._stopped = False
        self._threads: list[threading.Thread] = []
        self.start_ns: int | None = None
        self.rig_K: np.ndarray | None = None
        """K of the last `rig()` (the camera's report compares the first frame's own K with it)."""
        self.rig_notes: list[str] = []
        """What the last `rig()` withheld from the factory calibration, and why."""

    @property
    def calibration(self) -> Any:
        """The device's `dai.CalibrationHandler` (None before `open()` / `start()` or when unreadable)."""
        return None if self.pipe is None else self.pipe.calibration

    def rig(self, time_offset_s: float = 0.0) -> Rig:
        """`read_oak_rig` of the device's calibration for this socket and output size; what it withheld
        (corrupt extrinsics) is in `rig_notes`."""
        if self.calibration is None:
            why = (self.pipe.calibration_problem if self.pipe is not None else "") or "none is stored"
            raise CalibrationError(f"{self.device}: no calibration read from the device ({why}); pass the "
                                   f"camera's calibration with --rig FILE (a Kalibr camchain)")
        self.rig_notes = []
        rig = read_oak_rig(self.calibration, self.socket, self.width, self.height, fps=self.fps,
                           time_offset_s=time_offset_s, notes=self.rig_notes)
        self.rig_K = np.array(rig.camera.K)
        return rig

    def open(self) -> OakDevice:
        """Open the device and read its calibration (`rig()`), its streams not started yet: what takes
        time with the factory intrinsics (a model's warm-up) comes before images flow and are dropped.
        Idempotent; `start()` opens it when needed. Raises DeviceError (one line) when no device is
        attached or it cannot be opened."""
        with self._lock:
            self._open_locked()
        return self

    def _open_locked(self) -> OakPipeline:
        if self._stopped:
            raise DeviceError(f"{self.device}: opened or started after stop()")
        if self.pipe is None:
            try:
                pipe = self.pipeline_factory(self)
            except DavioError:
                raise
            except Exception as exc:  # noqa: BLE001 - any factory failure is a device error
                raise DeviceError(f"{self.device}: cannot be opened ({_one_line(exc)})") from None
            self.pipe = pipe
            if pipe.device_info:
                self.device = pipe.device_info
        return self.pipe

    def start(self) -> OakDevice:
        """Open the device (unless `open()` did), start the pipeline and both readers. Idempotent (both
        sources call it). Raises DeviceError (one line) when no device is attached, it cannot be opened or
        its pipeline cannot be started (the device is closed then)."""
        with self._lock:
            if self._started:
                if self._stopped:
                    raise DeviceError(f"{self.device}: start() after stop()")
                return self
            pipe = self._open_locked()
            if pipe.start is not None:
                try:
                    pipe.start()
                except BaseException:
                    self._stopped = True
                    pipe.stop()
                    raise
            self._started = True
            self.start_ns = time.monotonic_ns()
            self.camera._running = self.imu._running = True
            readers = (("camera", self.camera, pipe.camera_queue), ("imu", self.imu, pipe.imu_queue))
            for name, src, queue in readers:
                t = threading.Thread(target=self._read, args=(name, src, queue), name=f"davio-oak-{name}",
                                     daemon=True)
                self._threads.append(t)
                t.start()
            return self

    def stop(self) -> None:
        """Stop the readers and the pipeline (idempotent). Buffered events stay readable."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
            for src in (self.camera, self.imu):
                with src._cond:
                    src._stopping = True
                    src._cond.notify_all()
        if self.pipe is not None:
            self.pipe.stop()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=1.0)
        for src in (self.camera, self.imu):
            with src._cond:
                src._running = False
                src._cond.notify_all()

    close = stop

    def __enter__(self) -> OakDevice:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def report(self) -> dict[str, Any]:
        """Both sources' reports and the configuration."""
        return {"device": self.device, "socket": self.socket, "size": [self.width, self.height],
                "fps": self.fps, "imu_rate_hz": self.imu_rate_hz,
                "camera": self.camera.report(), "imu": self.imu.report()}

    # -- readers ---------------------------------------------------------------------------------
    def _fail(self, message: str) -> None:
        """The device is gone: both sources get the error (once), unless we are stopping."""
        err = DeviceError(message)
        for src in (self.camera, self.imu):
            with src._cond:
                if src.error is None and not src._stopping:
                    src.error = err
                src._cond.notify_all()

    def _read(self, name: str, src: OakCamera | OakImu, queue: Any) -> None:
        """Read one queue until stopped. A stream with no message, or whose messages give nothing usable
        (stamps gone back after a device clock reset, an accelerometer that stopped), for
        `stall_timeout_s` (`first_message_timeout_s` before the first) fails the device: waiting on would
        hang the run with no error."""
        poll = _dt.timedelta(seconds=_POLL_S)
        last = used = time.monotonic()
        got_any = got_use = False
        try:
            while not src._stopping:
                try:
                    msg = queue.get(poll)
                except Exception as exc:  # noqa: BLE001 - QueueException: closed (unplugged / stopped)
                    if not src._stopping:
                        self._fail(f"{self.device}: the {name} queue failed ({_one_line(exc)}): the device "
                                   f"was unplugged or crashed")
                    return
                now = time.monotonic()
                if msg is None:
                    limit = self.stall_timeout_s if got_any else self.first_message_timeout_s
                    if now - last > limit and not src._stopping:
                        what = "no message" if got_any else "no first message"
                        self._fail(f"{self.device}: {what} on the {name} queue for {now - last:.1f} s "
                                   f"(limit {limit:g} s): unplugged or stalled")
                        return
                    continue
                got_any, last = True, now
                limit = self.stall_timeout_s if got_use else self.first_message_timeout_s
                if src._ingest(msg, time.monotonic_ns()):
                    got_use, used = True, now
                    src._used()
                elif now - used > limit and not src._stopping:
                    what = "usable" if got_use else "first usable"
                    self._fail(f"{self.device}: messages on the {name} queue but no {what} "
                               f"{'frame' if src is self.camera else 'IMU sample'} for {now - used:.1f} s "
                               f"(limit {limit:g} s): {src.unusable_since() or 'none counted'}")
                    return
        except DavioError as exc:
            self._fail(str(exc))
        except Exception as exc:  # noqa: BLE001 - never a traceback from the thread
            self._fail(f"{self.device}: {name} reader failed: {type(exc).__name__}: {_one_line(exc)}")
        finally:
            with src._cond:
                src._running = False
                src._cond.notify_all()
