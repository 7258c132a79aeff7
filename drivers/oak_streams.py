"""The two sources of an OAK device: `OakCamera` (frames) and `OakImu` (samples), fed by its reader threads.

What each delivers, how it is stamped and what it counts is described in `drivers.oak`'s docstring; the
device and its threads live there, the pipeline factory in `drivers.oak_pipeline`, the calibration in
`drivers.oak_calib`.
"""
from __future__ import annotations

import dataclasses
import datetime as _dt
import threading
import time
from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.imu_pairing import ImuPairer
from drivers.kept_frames import KeptFrames
from runtime.errors import DavioError, DeviceError
from runtime.events import Frame, ImuSample

if TYPE_CHECKING:
    from drivers.oak import OakDevice

GAP_FACTOR = 1.5
"""A gyroscope stamp step above this many median steps is a gap (samples lost before the host)."""
GAP_MIN_STEPS = 10
GAP_STEPS = 64
"""Steps the median period is taken over, and the most gap flags kept waiting."""
RATE_TOLERANCE = 0.1
"""A measured IMU rate this far (relative) from the requested one is noted in the report."""

NEVER = 2**63 - 1
"""A stamp later than any frame (the floor of a source that will deliver nothing more)."""

_POLL_S = 0.05
"""How long one queue read waits (bounds how fast `stop()` and stalls are seen)."""


def timedelta_ns(td: _dt.timedelta) -> int:
    """Integer nanoseconds of a timedelta (exact: days, seconds and microseconds are integers)."""
    return (td.days * 86400 + td.seconds) * 1_000_000_000 + td.microseconds * 1000


def _report_ns(report: Any) -> int:
    """Device stamp of an IMU report, ns (0: the report is absent from its packet)."""
    ts = getattr(report, "tsDevice", None)
    if ts is not None:
        return int(ts.sec) * 1_000_000_000 + int(ts.nsec)
    return timedelta_ns(report.getTimestampDevice())


def frame_intrinsics(msg: Any) -> np.ndarray | None:
    """K (3,3) depthai computed for the image it delivered (crop, scale and sensor mode applied), or None
    when the frame carries no valid transformation."""
    try:
        t = msg.getTransformation()
        if not t.isValid():
            return None
        K = np.array(t.getIntrinsicMatrix(), dtype=np.float64)
    except Exception:  # noqa: BLE001 - an older message without a transformation: nothing to compare
        return None
    return K if K.shape == (3, 3) and np.isfinite(K).all() else None


def intrinsics_mismatch(rig_K: np.ndarray | None, device_K: np.ndarray | None, width: int,
                        height: int, tol: float = 0.01) -> str:
    """A note when the rig's K and the device's own K of the delivered image differ by more than `tol`
    (focal lengths relative, principal point relative to the image size); '' otherwise."""
    if rig_K is None or device_K is None:
        return ""
    f_rel = np.abs(np.diag(device_K)[:2] / np.diag(rig_K)[:2] - 1.0)
    c_rel = np.abs(device_K[:2, 2] - rig_K[:2, 2]) / np.array([width, height], float)
    if max(f_rel.max(), c_rel.max()) <= tol:
        return ""
    fmt = lambda K: f"fx {K[0, 0]:.1f} fy {K[1, 1]:.1f} cx {K[0, 2]:.1f} cy {K[1, 2]:.1f}"  # noqa: E731
    return (f"the device's own intrinsics of the delivered image ({fmt(device_K)}) differ from the rig's "
            f"({fmt(rig_K)}): the rig read from the factory calibration may not match the image; check it, "
            f"or pass a calibration of this output with --rig")


class _Source:
    """What both OAK sources share: the device, a condition, a buffer, the error."""

    def __init__(self, owner: OakDevice) -> None:
        self.owner = owner
        self._cond = threading.Condition()
        self._stopping = False
        self._running = False
        self.error: DavioError | None = None
        """The failure of the device (unplugged, stalled); `get` raises it once the buffer is drained."""
        self._counts_at_use: dict[str, int] = {}

    def _counts(self) -> dict[str, int]:
        """Counters that say why messages gave nothing usable (`unusable_since`): what was dropped, and
        for the IMU what arrived."""
        return {}

    def _used(self) -> None:
        """A message gave usable data: `unusable_since` counts from here."""
        self._counts_at_use = self._counts()

    def unusable_since(self) -> str:
        """The counters' increase since the last usable message ('' when none increased)."""
        now, then = self._counts(), self._counts_at_use
        return ", ".join(f"{n - then.get(k, 0)} {k}" for k, n in now.items() if n - then.get(k, 0))

    @property
    def device(self) -> str:
        return self.owner.device

    def start(self) -> Any:
        self.owner.start()
        return self

    def stop(self) -> None:
        self.owner.stop()

    close = stop

    def _take(self, buf: deque, timeout: float | None) -> Any:
        if not self.owner._started:
            raise DeviceError(f"{self.device}: get() after the device was stopped (or its start failed)"
                              if self.owner._stopped else f"{self.device}: get() before start()")
        deadline = None if timeout is None else time.monotonic() + max(0.0, float(timeout))
        with self._cond:
            while not buf:
                if self.error is not None:
                    raise self.error.with_traceback(None)
                if not self._running:
                    return None
                wait = _POLL_S if deadline is None else min(_POLL_S, deadline - time.monotonic())
                if wait <= 0:
                    return None
                self._cond.wait(wait)
            return buf.popleft()


class OakCamera(KeptFrames, _Source):
    """The camera source of an `OakDevice` (see the module docstring)."""

    def __init__(self, owner: OakDevice, keep_frames: int = 2, camera_id: int = 0) -> None:
        super().__init__(owner)
        self.keep_frames = int(keep_frames)
        self.camera_id = int(camera_id)
        self._buf: deque[Frame] = deque()
        self.frames = self.emitted = self.dropped_old = self.nonmonotonic = 0
        self.seq_gaps = self.seq_skipped = self.converted = 0
        self.conversion: str | None = None
        self.device_K: np.ndarray | None = None
        """The first frame's own intrinsics (`getTransformation().getIntrinsicMatrix()`), when valid."""
        self._last_t: int | None = None
        self._first_t: int | None = None
        self._last_seq: int | None = None

    def get(self, timeout: float | None = None) -> Frame | None:
        """The oldest kept frame, waiting up to `timeout` s (None: until one comes). None on timeout or
        once stopped and drained; raises the device's DeviceError once drained."""
        frame = self._take(self._buf, timeout)
        if frame is not None:
            with self._cond:
                self.emitted += 1
        return frame

    def min_future_ns(self) -> int:
        """A lower bound of the device-clock stamp of every frame `get` will still return: the oldest
        buffered frame's, else just after the last frame's (stamps increase); NEVER once nothing more
        will come, -NEVER before the first frame."""
        with self._cond:
            if self._buf:
                return self._buf[0].t_ns
            if self.error is not None or not self._running or self._stopping:
                return NEVER
            return -NEVER if self._last_t is None else self._last_t + 1

    def report(self) -> dict[str, Any]:
        """Counters: frames (kept), emitted, dropped_old (buffer), seq_gaps (jumps of the sequence number:
        the device or its queue skipped frames), seq_skipped (the frames skipped), nonmonotonic (dropped
        stamps), converted; the stamp source; error."""
        fps_m = self.fps_measured()
        notes = list(self.owner.rig_notes)      # what the factory calibration withheld (corrupt extrinsics)
        mismatch = intrinsics_mismatch(self.owner.rig_K, self.device_K, self.owner.width, self.owner.height)
        if mismatch:
            notes.append(mismatch)
        return {"device": self.device, "socket": self.owner.socket, "kind": "oak",
                "size": [self.owner.width, self.owner.height], "fps_requested": self.owner.fps,
                "fps_measured": None if fps_m is None else round(fps_m, 3),
                "frames": self.frames, "emitted": self.emitted, "dropped_old": self.dropped_old,
                "seq_gaps": self.seq_gaps, "seq_skipped": self.seq_skipped, "nonmonotonic": self.nonmonotonic,
                "converted": self.converted, "conversion": self.conversion, "keep_frames": self.keep_frames,
                "device_K": None if self.device_K is None else self.device_K.tolist(),
                "stamps": "device clock, mid-exposure (getTimestampDevice(MIDDLE))",
                "error": None if self.error is None else str(self.error), "notes": notes}

    # reader side
    def _counts(self) -> dict[str, int]:
        return {"frames whose device stamp did not increase (the device clock went back or jumped ahead)":
                self.nonmonotonic}

    def _ingest(self, msg: Any, t_host: int) -> bool:
        """Take one ImgFrame; True when it gave a frame (kept, or dropped by the newest-frames buffer)."""
        from drivers import oak_pipeline  # at call time: the factory module's depthai (patched in tests)

        dai = oak_pipeline._import_depthai()
        t_ns = timedelta_ns(msg.getTimestampDevice(dai.CameraExposureOffset.MIDDLE))
        seq = int(msg.getSequenceNum())
        if self.device_K is None:
            self.device_K = frame_intrinsics(msg)
        if self._last_seq is not None and seq > self._last_seq + 1:
            self.seq_gaps += 1
            self.seq_skipped += seq - self._last_seq - 1
        self._last_seq = seq
        if self._last_t is not None and t_ns <= self._last_t:
            self.nonmonotonic += 1
            return False
        grey = self._to_grey(dai, msg)
        if grey.shape != (self.owner.height, self.owner.width):
            raise DeviceError(f"{self.device}: delivers {grey.shape[1]}x{grey.shape[0]} images, "
                              f"{self.owner.width}x{self.owner.height} were requested")
        frame = Frame(t_ns, grey, self.camera_id, meta={"seq": seq, "host_ns": t_host})
        with self._cond:
            if self._stopping:
                return False
            self._keep_newest(frame)
        return True

    def _to_grey(self, dai: Any, msg: Any) -> np.ndarray:
        kind = msg.getType()
        w, h = int(msg.getWidth()), int(msg.getHeight())
        T = dai.ImgFrame.Type
        if kind in (T.GRAY8, T.RAW8, T.NV12, T.NV21, T.YUV420p):
            stride = int(msg.getStride()) or w
            data = np.asarray(msg.getData(), dtype=np.uint8).reshape(-1)
            if data.size < h * stride:
                raise DeviceError(f"{self.device}: a {w}x{h} {kind.name} frame holds {data.size} bytes")
            img = data[: h * stride].reshape(h, stride)[:, :w]
            if kind not in (T.GRAY8, T.RAW8):
                self.converted += 1
                self.conversion = f"{kind.name} luma plane"
            return np.ascontiguousarray(img)
        import cv2

        img = np.asarray(msg.getCvFrame())
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
            self.converted += 1
            self.conversion = f"{kind.name} to grey"
        if img.dtype != np.uint8 or img.ndim != 2:
            raise DeviceError(f"{self.device}: unsupported image type {kind.name}")
        return np.ascontiguousarray(img)


class OakImu(_Source):
    """The IMU source of an `OakDevice` (see the module docstring)."""

    def __init__(self, owner: OakDevice, capacity: int = 1500) -> None:
        super().__init__(owner)
        self.capacity = int(capacity)
        self.pairer = ImuPairer()
        self._queue: deque[ImuSample] = deque()
        self.batches = self.packets = self.enqueued = self.delivered = 0
        self.overflow = 0
        self._overflow_pending = 0
        self.gaps = self.lost_before_host = 0
        self._steps: deque[int] = deque(maxlen=GAP_STEPS)
        self._last_gyro_ns: int | None = None
        self._gap_at: dict[int, int] = {}      # gyro stamp -> samples missing right before it
        self.port = None  # LiveDriver._describe looks for .port or .device

    def get(self, timeout: float | None = None) -> ImuSample | None:
        """The next sample (device-clock int64 ns, gyro rad/s, accel m/s^2 in the DepthAI IMU frame).
        None on timeout or once stopped and drained; raises the device's DeviceError once drained."""
        s = self._take(self._queue, timeout)
        if s is not None:
            with self._cond:
                self.delivered += 1
        return s

    def _check_gap(self, t_ns: int) -> None:
        """A gyroscope stamp more than GAP_FACTOR median periods after the previous one: the samples
        between were lost before the host (the device's queue dropped batches); flag the sample."""
        last = self._last_gyro_ns
        if last is not None and t_ns <= last:
            return                           # a repeated report: the pairer counts and drops it
        self._last_gyro_ns = t_ns
        if last is None:
            return
        step = t_ns - last
        if len(self._steps) >= GAP_MIN_STEPS:
            period = float(np.median(self._steps))
            if step > GAP_FACTOR * period:
                lost = max(1, int(round(step / period)) - 1)
                self.gaps += 1
                self.lost_before_host += lost
                self._gap_at[t_ns] = lost
        self._steps.append(step)     # gaps too: the median of 64 ignores a few, and follows a rate change

    def take_overflow(self) -> int:
        """Samples lost to overflow since the last call (non-zero: reset the IMU preintegration)."""
        with self._cond:
            n, self._overflow_pending = self._overflow_pending, 0
            return n

    def queued(self) -> int:
        return len(self._queue)

    def report(self) -> dict[str, Any]:
        out: dict[str, Any] = {"driver": "oak_imu", "device": self.device, "rate_hz": self.owner.imu_rate_hz,
                               "batches": self.batches, "packets": self.packets, "samples": self.enqueued,
                               "delivered": self.delivered, "queued": len(self._queue),
                               "queue_capacity": self.capacity, "overflow": self.overflow,
                               "gaps": self.gaps, "lost_before_host": self.lost_before_host}
        out.update(self.pairer.counts())
        notes = []
        requested = float(self.owner.imu_rate_hz)   # out["rate_hz"]
        out["rate_hz_measured"] = None
        if len(self._steps) >= GAP_MIN_STEPS:  # the gyroscope's median stamp step over the last GAP_STEPS
            measured = 1e9 / float(np.median(self._steps))
            out["rate_hz_measured"] = round(measured, 1)
            if abs(measured / requested - 1.0) > RATE_TOLERANCE:
                notes.append(f"the IMU runs at {measured:.0f} Hz, not the {requested:g} Hz requested (the "
                             f"chip rounds to a rate it supports)")
        if self.gaps:
            notes.append(f"{self.gaps} gaps in the gyroscope stamps: about {self.lost_before_host} samples "
                         f"lost before reaching the host (each flagged on the sample after it)")
        if self.pairer.interpolated:
            notes.append(f"{self.pairer.interpolated} accelerometer values interpolated to gyroscope stamps")
        if self.pairer.unpaired:
            notes.append(f"{self.pairer.unpaired} gyroscope reports without accelerometer reports around "
                         f"them dropped")
        if self.pairer.repeated:
            notes.append(f"{self.pairer.repeated} reports repeating or preceding their stream's stamp "
                         f"dropped")
        out["notes"] = notes
        out["error"] = None if self.error is None else str(self.error)
        return out

    def _counts(self) -> dict[str, int]:
        p = self.pairer
        return {"accelerometer reports": p.accel_reports, "gyroscope reports": p.gyro_reports,
                "reports dropped as repeating or preceding their stream's stamp": p.repeated,
                "gyroscope reports dropped without accelerometer reports around them": p.unpaired}

    def _ingest(self, msg: Any, t_host: int) -> bool:
        """Take one IMUData batch; True when it gave samples."""
        self.batches += 1
        p = self.pairer
        for pkt in msg.packets:
            self.packets += 1
            a, g = pkt.acceleroMeter, pkt.gyroscope
            ta, tg = _report_ns(a), _report_ns(g)
            if ta:
                p.add_accel(ta, (a.x, a.y, a.z))
            if tg:
                self._check_gap(tg)
                p.add_gyro(tg, (g.x, g.y, g.z))
        samples = p.pop()
        if not samples:
            return False
        if self._gap_at:
            samples = [dataclasses.replace(x, lost_before=x.lost_before + self._gap_at.pop(x.t_ns))
                       if x.t_ns in self._gap_at else x for x in samples]
            if len(self._gap_at) > GAP_STEPS:        # stamps the pairer dropped never come
                for t in sorted(self._gap_at)[:-GAP_STEPS]:
                    del self._gap_at[t]
        with self._cond:
            for s in samples:
                if len(self._queue) >= self.capacity:
                    self._queue.popleft()
                    self.overflow += 1
                    self._overflow_pending += 1
                self._queue.append(s)
            self.enqueued += len(samples)
            self._cond.notify_all()
        return True
