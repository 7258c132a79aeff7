"""OakDevice / read_oak_rig without an OAK (notes/drivers.md §1).

- In process: real depthai message classes (`dai.ImgFrame`, `dai.IMUData` / `IMUPacket` /
  `IMUReport*`, built host-side) are fed through `FakeQueue`s (the `dai.MessageQueue` contract:
  `get(timedelta)` returns a message or None, raises once closed) injected with `pipeline_factory`.
- In a subprocess: the same driver over REAL `dai.MessageQueue`s of a host-only `dai.Pipeline(False)`
  whose `ThreadedHostNode` sends the recorded messages, merged by LiveDriver; then the pipeline is
  stopped under the readers (what an unplug does to the queues). A subprocess, because tearing down a
  host-only pipeline with a Python node can hang or crash the interpreter at exit (measured).
- Calibration: tests/drivers/fixtures/oak_calib.json, written by `make_calibration()` below with
  `eepromToJsonFile` (regenerate: `python tests/drivers/test_oak.py`), read with
  `dai.CalibrationHandler(path)`.
The probe and the pipeline factory (`drivers.oak_pipeline`) are tested in test_oak_pipeline.py.
"""
from __future__ import annotations

import datetime as dt
import json
import os
import queue
import re
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("DEPTHAI_LEVEL", "error")
dai = pytest.importorskip("depthai")

from drivers.live import LiveDriver  # noqa: E402
from drivers.oak import (  # noqa: E402
    NEVER,
    OakDevice,
    OakPipeline,
    timedelta_ns,
)
from drivers.oak_calib import check_extrinsics_direction, read_oak_rig  # noqa: E402
from runtime.errors import CalibrationError, DeviceError  # noqa: E402
from runtime.events import Frame, ImuSample  # noqa: E402

FIXTURE = Path(__file__).parent / "fixtures" / "oak_calib.json"
ROOT = Path(__file__).resolve().parents[2]
W, H = 64, 40
EXPOSURE_US = 8000
T0 = 1_000 * 10**9  # device clock at the first frame's END of exposure
G = 9.80665


# -- synthetic rig geometry (ground truth for the calibration fixture) --------------------------
def rot(axis: tuple[float, float, float], deg: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.radians(deg)
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


def rigid(R: np.ndarray, p: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


# x_C = T x_I (IMU -> right camera CAM_C) and x_C = T x_B (left -> right), metres. The rotation of the
# IMU is not symmetric, so its direction is observable from gravity.
T_CcI = rigid(rot((1, 2, 3), 100.0), (0.021, -0.0052, 0.0113))
T_CcB = rigid(rot((0, 1, 0), 0.5), (-0.075, 0.0002, 0.0))
T_IB_TRUE = np.linalg.inv(T_CcI) @ T_CcB  # what read_oak_rig(CAM_B) must return as T_IC
K_MONO = [[800.0, 0.0, 640.5], [0.0, 801.0, 400.25], [0.0, 0.0, 1.0]]
RADTAN5 = [-0.11, 0.07, 0.0004, -0.0003, -0.012]
EQUI4 = [0.02, -0.01, 0.003, -0.0005]
RATIONAL = [-5.6, 16.1, 0.0002, 0.0001, -2.3, -5.5, 15.8, -1.9, 0, 0, 0, 0, 0, 0]


def make_calibration() -> dai.CalibrationHandler:
    """CAM_A colour (rational model), CAM_B left (radtan, k3), CAM_C right (fisheye, origin);
    IMU linked to CAM_C. Translations in centimetres, as depthai stores them; each link written in
    depthai's convention x_dst = M x_src."""
    S = dai.CameraBoardSocket
    c = dai.CalibrationHandler()
    for sock, K, size, model, dist in (
            (S.CAM_A, [[1500.0, 0, 960.0], [0, 1500.0, 540.0], [0, 0, 1]], (1920, 1080),
             dai.CameraModel.Perspective, RATIONAL),
            (S.CAM_B, K_MONO, (1280, 800), dai.CameraModel.Perspective, RADTAN5 + [0.0] * 9),
            (S.CAM_C, K_MONO, (1280, 800), dai.CameraModel.Fisheye, EQUI4)):
        c.setCameraIntrinsics(sock, K, *size)
        c.setCameraType(sock, model)
        c.setDistortionCoefficients(sock, dist)
    c.setCameraExtrinsics(S.CAM_B, S.CAM_C, T_CcB[:3, :3].tolist(), (T_CcB[:3, 3] * 100).tolist())
    c.setImuExtrinsics(S.CAM_C, T_CcI[:3, :3].tolist(), (T_CcI[:3, 3] * 100).tolist())
    return c


@pytest.fixture(scope="module")
def calib() -> dai.CalibrationHandler:
    return dai.CalibrationHandler(str(FIXTURE))


# -- recorded messages (real depthai classes) ---------------------------------------------------
def img_frame(i: int, period_ns: int, w: int = W, h: int = H, kind: str = "GRAY8") -> dai.ImgFrame:
    f = dai.ImgFrame()
    f.setType(getattr(dai.ImgFrame.Type, kind))
    f.setWidth(w)
    f.setHeight(h)
    n = w * h * 3 // 2 if kind == "NV12" else w * h
    data = np.full(n, 0, np.uint8)
    data[: w * h] = (np.arange(w * h) + i) % 251
    f.setData(data)
    f.setSequenceNum(i)
    f.setTimestampDevice(dt.timedelta(microseconds=(T0 + i * period_ns) // 1000))
    cs = f.cam
    cs.exposureTimeUs = EXPOSURE_US
    f.cam = cs
    return f


def report(cls: type, t_ns: int, xyz: tuple[float, float, float]) -> object:
    r = cls()
    r.x, r.y, r.z = xyz
    ts = dai.Timestamp()
    ts.sec, ts.nsec = divmod(t_ns, 10**9)
    r.tsDevice = ts
    return r


def imu_batch(stamps: list[tuple[int | None, int | None]],
              accel: tuple[float, ...] = (0.0, 0.0, G)) -> dai.IMUData:
    """One IMUData: a packet per (accel stamp, gyro stamp); None leaves that report out. Gyro x = the
    stamp in seconds (so pairing can be checked), accel = `accel` + (stamp in s, 0, 0)."""
    d = dai.IMUData()
    pkts = []
    for ta, tg in stamps:
        p = dai.IMUPacket()
        if ta is not None:
            p.acceleroMeter = report(dai.IMUReportAccelerometer, ta, tuple(np.add(accel, (ta * 1e-9, 0, 0))))
        if tg is not None:
            p.gyroscope = report(dai.IMUReportGyroscope, tg, (tg * 1e-9, 0.01, -0.02))
        pkts.append(p)
    d.packets = pkts
    return d


class QueueClosed(Exception):
    """Stands in for dai.MessageQueue.QueueException."""


class FakeQueue:
    """The dai.MessageQueue contract: get(timedelta) -> message | None; raises once closed."""

    def __init__(self) -> None:
        self.q: queue.Queue = queue.Queue()
        self.closed = False

    def put(self, msg: object) -> None:
        self.q.put(msg)

    def close(self) -> None:
        self.closed = True

    def get(self, timeout: dt.timedelta) -> object:
        if self.closed:
            raise QueueClosed("MessageQueue was closed")
        try:
            return self.q.get(timeout=timeout.total_seconds())
        except queue.Empty:
            return None


class FakePipe:
    def __init__(self, *queues: FakeQueue) -> None:
        self.queues = queues
        self.stopped = 0

    def stop(self) -> None:
        self.stopped += 1
        for q in self.queues:
            q.close()


def fake_device(calibration: object = None, **kw: object) -> tuple[OakDevice, FakeQueue, FakeQueue, FakePipe]:
    cq, iq = FakeQueue(), FakeQueue()
    pipe = FakePipe(cq, iq)
    kw.setdefault("stall_timeout_s", 5.0)
    dev = OakDevice("CAM_B", W, H, 30.0, 200,
                    pipeline_factory=lambda d: OakPipeline(cq, iq, pipe, calibration, "OAK fake"), **kw)
    return dev, cq, iq, pipe


def wait_until(cond: object, timeout: float = 2.0) -> None:
    t_end = time.monotonic() + timeout
    while not cond():  # type: ignore[operator]
        assert time.monotonic() < t_end, "timed out"
        time.sleep(0.002)


# -- camera -------------------------------------------------------------------------------------
def test_frames_grey_sized_mid_exposure_device_stamps_and_drops() -> None:
    dev, cq, _, pipe = fake_device(keep_frames=2)
    period = 33_333_333
    for i in range(5):
        cq.put(img_frame(i, period))
    with dev:
        wait_until(lambda: dev.camera.frames + dev.camera.dropped_old >= 5 and dev.camera.frames >= 5)
        assert dev.camera.min_future_ns() == dev.camera._buf[0].t_ns
        frames = [dev.camera.get(0.5), dev.camera.get(0.5)]
        assert dev.camera.get(0.01) is None
        last = frames[-1].t_ns
        assert dev.camera.min_future_ns() == last + 1  # later frames are stamped after it
        rep = dev.camera.report()
    assert pipe.stopped == 1
    assert rep["frames"] == 5 and rep["dropped_old"] == 3 and rep["emitted"] == 2 and rep["seq_gaps"] == 0
    for f, i in zip(frames, (3, 4), strict=True):
        assert isinstance(f, Frame) and f.image.dtype == np.uint8 and f.image.shape == (H, W)
        assert f.meta["seq"] == i
        assert int(f.image[0, 0]) == i % 251
        # device clock, mid-exposure: end-of-exposure stamp minus half the exposure, int ns
        assert type(f.t_ns) is int
        assert f.t_ns == (T0 + i * period) // 1000 * 1000 - EXPOSURE_US * 500
    assert dev.camera.min_future_ns() == NEVER  # stopped


def test_sequence_gaps_nonmonotonic_and_nv12_luma() -> None:
    dev, cq, _, _ = fake_device(keep_frames=10)
    period = 33_333_333
    for i in (0, 1, 4):  # the device skipped 2 and 3
        cq.put(img_frame(i, period))
    cq.put(img_frame(5, -period))  # a stamp that goes back
    nv = img_frame(6, period, kind="NV12")
    cq.put(nv)
    with dev:
        wait_until(lambda: dev.camera.frames + dev.camera.nonmonotonic >= 5)
        frames = [dev.camera.get(0.5) for _ in range(4)]
        rep = dev.camera.report()
    assert [f.meta["seq"] for f in frames] == [0, 1, 4, 6]
    assert rep["seq_gaps"] == 1 and rep["seq_skipped"] == 2   # one jump: 2 and 3 skipped
    assert rep["nonmonotonic"] == 1                             # 5 went back in time
    assert rep["converted"] == 1 and "NV12" in rep["conversion"]
    assert frames[-1].image.shape == (H, W) and int(frames[-1].image[0, 1]) == 7


def test_wrong_size_is_a_device_error() -> None:
    dev, cq, _, _ = fake_device()
    cq.put(img_frame(0, 1, w=32, h=20))
    with dev:
        with pytest.raises(DeviceError, match="32x20 images, 64x40 were requested"):
            dev.camera.get(1.0)


# -- IMU ----------------------------------------------------------------------------------------
def _drain_imu(dev: OakDevice, batches: int) -> tuple[list, dict]:
    """Start the device, wait for `batches` IMU batches, take every sample; (samples, IMU report)."""
    with dev:
        wait_until(lambda: dev.imu.batches == batches)
        out = []
        while (s := dev.imu.get(0.05)) is not None:
            out.append(s)
        return out, dev.imu.report()


def test_imu_batches_paired_ordered_device_clock() -> None:
    dev, _, iq, _ = fake_device()
    ms = 1_000_000
    t = [T0 + k * 5 * ms for k in range(30)]
    iq.put(imu_batch([(x, x) for x in t[:10]]))  # a batch of 10 packets, equal stamps
    iq.put(imu_batch([(x, x) for x in t[9:20]]))  # repeats the last packet of the previous batch
    # then accel and gyro 1 ms apart; one packet without gyro, one without accel
    iq.put(imu_batch([(x, x + ms) for x in t[20:25]] + [(t[25], None), (None, t[25] + ms)]
                     + [(x, x + ms) for x in t[26:30]]))
    out, rep = _drain_imu(dev, batches=3)
    stamps = [s.t_ns for s in out]
    assert stamps == t[:20] + [x + ms for x in t[20:29]]  # the last gyro waits for the next accel
    assert all(isinstance(s, ImuSample) and type(s.t_ns) is int for s in out)
    for s in out:  # gyro x carries its stamp; accel x carries the (interpolated) accel stamp
        assert s.gyro[0] == pytest.approx(s.t_ns * 1e-9, abs=1e-3)
        assert s.accel[0] == pytest.approx(s.t_ns * 1e-9, abs=1e-3)
        assert s.accel[2] == pytest.approx(G, abs=1e-5)
    assert rep["packets"] == 32 and rep["repeated"] == 2 and rep["interpolated"] == 9
    assert rep["samples"] == 29 and rep["overflow"] == 0


def test_imu_overflow_counted() -> None:
    dev, _, iq, _ = fake_device(imu_queue_seconds=0.05)  # 15 samples at 200 Hz x 1.5
    iq.put(imu_batch([(T0 + k * 5_000_000,) * 2 for k in range(40)]))
    with dev:
        wait_until(lambda: dev.imu.enqueued == 40)          # `batches` counts a batch before its samples
        assert dev.imu.queued() == 15 and dev.imu.take_overflow() == 25 and dev.imu.take_overflow() == 0
        assert dev.imu.get(0.1).t_ns == T0 + 25 * 5_000_000


def test_samples_after_batches_lost_before_the_host_are_flagged() -> None:
    """The device's queue dropped batches: the gyroscope stamps jump. The sample after the jump carries
    the number of samples missing (so the filter treats the interval as a gap), and no other one does;
    stamp jitter of a tenth of a period is not a gap."""
    dev, _, iq, _ = fake_device()
    rng = np.random.default_rng(0)
    ms = 1_000_000
    t = [T0 + k * 5 * ms + int(rng.integers(-ms // 2, ms // 2)) for k in range(60)]
    kept = t[:30] + t[34:50] + t[51:]           # 4 samples lost, then 1
    iq.put(imu_batch([(x, x) for x in kept[:20]]))
    iq.put(imu_batch([(x, x) for x in kept[20:40]]))
    iq.put(imu_batch([(x, x) for x in kept[40:]]))
    out, rep = _drain_imu(dev, batches=3)
    assert [s.t_ns for s in out] == kept
    lost = {s.t_ns: s.lost_before for s in out if s.lost_before}
    assert lost == {t[34]: 4, t[51]: 1}
    assert rep["gaps"] == 2 and rep["lost_before_host"] == 5 and rep["overflow"] == 0
    assert any("5 samples lost before reaching the host" in n for n in rep["notes"])
    # 5 ms stamp steps: the 200 Hz requested, not noted
    assert rep["rate_hz"] == 200 and rep["rate_hz_measured"] == pytest.approx(200, rel=0.02)
    assert not any("Hz requested" in n for n in rep["notes"])


def test_an_imu_rate_other_than_the_requested_one_is_noted() -> None:
    dev, _, iq, _ = fake_device()                       # 200 Hz requested
    iq.put(imu_batch([(T0 + k * 2_500_000,) * 2 for k in range(40)]))   # the chip gives 400 Hz
    out, rep = _drain_imu(dev, batches=1)
    assert len(out) == 40 and rep["rate_hz_measured"] == pytest.approx(400.0)
    assert any("the IMU runs at 400 Hz, not the 200 Hz requested" in n for n in rep["notes"])


def test_gap_detection_follows_a_rate_change_instead_of_flagging_every_sample() -> None:
    """A start at twice the rate (a FIFO flush) must not lock the median period: flags stop once the window
    holds mostly the steady rate's steps."""
    dev, _, iq, _ = fake_device()
    ms = 1_000_000
    t = [T0 + k * 2 * ms for k in range(20)]
    t += [t[-1] + k * 5 * ms for k in range(1, 181)]
    for k in range(0, 200, 10):                       # the device's batches hold at most 10 reports
        iq.put(imu_batch([(x, x) for x in t[k:k + 10]]))
    out, rep = _drain_imu(dev, batches=20)
    assert len(out) == 200
    flagged = [k for k, s in enumerate(out) if s.lost_before]
    assert flagged and max(flagged) < 20 + 64 and rep["gaps"] == len(flagged)


# -- errors -------------------------------------------------------------------------------------
def test_disconnect_surfaces_as_device_error_after_drain() -> None:
    dev, cq, iq, _ = fake_device(keep_frames=4)
    for i in range(2):
        cq.put(img_frame(i, 33_333_333))
    iq.put(imu_batch([(T0, T0)]))
    with dev:
        wait_until(lambda: dev.camera.frames == 2 and dev.imu.enqueued == 1)
        cq.close()  # the device goes away: depthai closes the queues
        wait_until(lambda: dev.camera.error is not None)
        assert isinstance(dev.imu.error, DeviceError)  # the whole device is gone
        assert "unplugged" in str(dev.camera.error) and "\n" not in str(dev.camera.error)
        assert dev.camera.get(0.1) is not None and dev.camera.get(0.1) is not None  # drained first
        with pytest.raises(DeviceError, match="camera queue failed"):
            dev.camera.get(0.1)
        assert dev.imu.get(0.1) is not None
        with pytest.raises(DeviceError):
            dev.imu.get(0.1)
        assert dev.camera.min_future_ns() == NEVER
    dev.stop()  # idempotent


def test_stall_is_a_device_error() -> None:
    dev, _, _, _ = fake_device(first_message_timeout_s=0.2)
    with dev:
        with pytest.raises(DeviceError, match="no first message on the (camera|imu) queue"):
            dev.camera.get(2.0)


def feed(q: FakeQueue, messages: list, period_s: float = 0.01) -> threading.Thread:
    """A device thread putting `messages` into `q` one every `period_s` (messages keep arriving)."""
    def run() -> None:
        for m in messages:
            q.put(m)
            time.sleep(period_s)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_frames_whose_stamps_went_back_for_good_fail_the_device_instead_of_hanging() -> None:
    """A device clock reset: every later frame is older than the last one kept and is dropped. The
    messages kept the stream 'alive', so no stall was seen and the run waited without end."""
    dev, cq, iq, _ = fake_device(keep_frames=10, stall_timeout_s=0.3)
    period = 33_333_333
    back = [img_frame(i, period) for i in range(5, 105)]
    for f in back:                                   # restamped 10 s earlier, still increasing
        f.setTimestampDevice(f.getTimestampDevice() - dt.timedelta(seconds=10))
    with dev:
        for i in range(5):
            cq.put(img_frame(i, period))
        wait_until(lambda: dev.camera.frames == 5)
        feed(cq, back)
        wait_until(lambda: dev.camera.error is not None, timeout=5.0)
        err = str(dev.camera.error)
        assert "messages on the camera queue but no usable frame for" in err and "limit 0.3 s" in err
        assert "frames whose device stamp did not increase" in err and "\n" not in err
        assert isinstance(dev.imu.error, DeviceError)          # the whole device is failed
        assert [dev.camera.get(0.1).meta["seq"] for _ in range(5)] == list(range(5))   # drained first
        with pytest.raises(DeviceError, match="no usable frame"):
            dev.camera.get(0.1)


def test_an_accelerometer_that_stops_fails_the_device_instead_of_hanging() -> None:
    """Gyroscope reports alone pair into no sample: the IMU delivered nothing, with messages flowing."""
    dev, cq, iq, _ = fake_device(stall_timeout_s=0.3)
    ms = 1_000_000
    with dev:
        iq.put(imu_batch([(T0 + k * 5 * ms,) * 2 for k in range(10)]))
        wait_until(lambda: dev.imu.enqueued >= 9)
        feed(iq, [imu_batch([(None, T0 + (10 + k) * 5 * ms)]) for k in range(200)], 0.005)
        wait_until(lambda: dev.imu.error is not None, timeout=5.0)
        err = str(dev.imu.error)
        assert "messages on the imu queue but no usable IMU sample for" in err
        assert "gyroscope reports" in err and "accelerometer reports" not in err   # none came since


def test_factory_failure_is_one_line_device_error() -> None:
    def boom(d: OakDevice) -> OakPipeline:
        raise RuntimeError("X_LINK_ERROR\nsecond line")

    with pytest.raises(DeviceError, match=r"^OAK: cannot be opened \(X_LINK_ERROR\)$"):
        OakDevice(pipeline_factory=boom).start()
    with pytest.raises(DeviceError, match="socket"):
        OakDevice(socket="CAM_Z")
    for rate in (0.5, float("nan"), 0):   # int(0.5) would have been a rate of 0 Hz
        with pytest.raises(DeviceError, match=r"imu_rate_hz >= 1 \(whole Hz\)"):
            OakDevice(imu_rate_hz=rate)


def test_open_reads_the_calibration_before_the_streams_start(calib: dai.CalibrationHandler) -> None:
    """open() gives the factory calibration (rig()) with the streams not started: a model can warm up with
    its intrinsics before images flow; start() starts them once. A start that fails closes the device."""
    cq, iq = FakeQueue(), FakeQueue()
    pipe = FakePipe(cq, iq)
    starts: list[int] = []
    dev = OakDevice("CAM_B", W, H, 30.0, 200, pipeline_factory=lambda d: OakPipeline(
        cq, iq, pipe, calib, "OAK fake", None, lambda: starts.append(1)))
    assert dev.open() is dev and dev.open() is dev                       # idempotent
    assert dev.rig().camera.width == W and starts == [] and not dev._threads
    cq.put(img_frame(0, 33_333_333))
    dev.start()
    dev.start()
    assert starts == [1] and len(dev._threads) == 2
    assert dev.camera.get(2.0) is not None
    dev.stop()

    def failing_start() -> None:
        raise DeviceError("OAK fake: the pipeline could not be started (X_LINK_ERROR)")

    pipe2 = FakePipe(FakeQueue(), FakeQueue())
    dev2 = OakDevice("CAM_B", W, H, 30.0, 200, pipeline_factory=lambda d: OakPipeline(
        FakeQueue(), FakeQueue(), pipe2, calib, "OAK fake", None, failing_start))
    dev2.open()
    with pytest.raises(DeviceError, match="could not be started"):
        dev2.start()
    assert pipe2.stopped == 1 and not dev2._threads
    with pytest.raises(DeviceError, match="after stop"):
        dev2.start()
    with pytest.raises(DeviceError, match="get\\(\\) after the device was stopped"):
        dev2.camera.get(0.1)
    # opened, never started, then stopped: the pipeline (and with it the device) is closed, nothing started
    pipe3 = FakePipe(FakeQueue(), FakeQueue())
    dev3 = OakDevice("CAM_B", W, H, 30.0, 200, pipeline_factory=lambda d: OakPipeline(
        FakeQueue(), FakeQueue(), pipe3, calib, "OAK fake", None, lambda: starts.append(3)))
    dev3.open()
    dev3.stop()
    assert pipe3.stopped == 1 and 3 not in starts


# -- LiveDriver over the fake pipeline -----------------------------------------------------------
def feed_live(cq: FakeQueue, iq: FakeQueue, seconds: float = 0.5, speed: float = 4.0) -> threading.Thread:
    """Device time T0.. at 30 fps and 200 Hz, IMU in batches of 2, sent in device-time order at
    `speed` x real time; frames arrive 10 ms (device time) after their end of exposure."""
    period, imu_dt = 33_333_333, 5_000_000

    def run() -> None:
        events = []
        for i in range(int(seconds * 30)):
            events.append((T0 + i * period + 10_000_000, 1, img_frame(i, period)))
        for k in range(0, int(seconds * 200), 2):
            ts = [T0 - 50_000_000 + (k + j) * imu_dt for j in range(2)]
            events.append((ts[-1] + 1_000_000, 0, imu_batch([(x, x) for x in ts])))
        events.sort(key=lambda e: (e[0], e[1]))
        start, t_first = time.monotonic(), events[0][0]
        for t, kind, msg in events:
            delay = (t - t_first) / 1e9 / speed - (time.monotonic() - start)
            if delay > 0:
                time.sleep(delay)
            (cq if kind else iq).put(msg)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def test_live_driver_over_fake_pipeline_time_ordered() -> None:
    # every frame kept and a long IMU wait: a loaded machine that starves this thread must not
    # drop frames from the newest-frames buffer or release them ahead of the IMU (CI did both)
    dev, cq, iq, _ = fake_device(keep_frames=64)
    feeder = feed_live(cq, iq, seconds=1.0)
    live = LiveDriver(dev.camera, dev.imu, imu_wait_s=2.0)
    events = []
    t_end = time.monotonic() + 5.0
    for ev in live.events():
        events.append(ev)
        if sum(isinstance(e, Frame) for e in events) >= 14 or time.monotonic() > t_end:
            live.stop()
    feeder.join(2.0)
    frames = [e for e in events if isinstance(e, Frame)]
    imu = [e for e in events if isinstance(e, ImuSample)]
    assert len(frames) >= 14 and len(imu) > 50
    keys = [(e.t_ns, 0 if isinstance(e, ImuSample) else 1) for e in events]
    assert keys == sorted(keys)
    for f in frames[1:]:  # every frame is preceded by IMU samples reaching its stamp
        before = [s.t_ns for s in imu if s.t_ns <= f.t_ns]
        assert before and f.t_ns - before[-1] < 5_000_000
    rep = live.report()
    assert rep["live"]["frames_ahead_of_imu"] == 0 and rep["sources"]["camera"]["socket"] == "CAM_B"


# -- real depthai queues (host-only pipeline) in a subprocess ------------------------------------
ROUND_TRIP = textwrap.dedent("""
    import datetime as dt, json, os, sys, time
    sys.path[:0] = [{root!r}, {tests!r}]
    import depthai as dai
    import test_oak as t
    from drivers.live import LiveDriver
    from drivers.oak import OakDevice, OakPipeline
    from runtime.errors import DeviceError
    from runtime.events import Frame

    class Src(dai.node.ThreadedHostNode):
        def __init__(self):
            super().__init__()
            self.img = self.createOutput()
            self.imu = self.createOutput()
        def run(self):
            period = 33_333_333
            for i in range(12):
                ts = [t.T0 - 20_000_000 + (7 * i + j) * 5_000_000 for j in range(7)]
                self.imu.send(t.imu_batch([(x, x) for x in ts]))
                self.img.send(t.img_frame(i, period))
                time.sleep(0.01)
            while self.isRunning():
                time.sleep(0.01)

    keep = []
    def factory(d):
        p = dai.Pipeline(False)
        s = p.create(Src)
        q_img = s.img.createOutputQueue(16, False)   # room for all 12 frames on a loaded machine
        q_imu = s.imu.createOutputQueue(50, False)
        p.start()
        keep.append((p, s))
        return OakPipeline(q_img, q_imu, p, dai.CalibrationHandler(str(t.FIXTURE)), "OAK host-only")

    out = {{}}
    dev = OakDevice("CAM_B", t.W, t.H, 30.0, 200, pipeline_factory=factory, keep_frames=16)
    live = LiveDriver(dev.camera, dev.imu, rig=None, imu_wait_s=2.0)
    evs = []
    t_end = time.monotonic() + 4
    for ev in live.events():
        evs.append((ev.t_ns, isinstance(ev, Frame), ev.image.shape if isinstance(ev, Frame) else None))
        if sum(e[1] for e in evs) >= 10 or time.monotonic() > t_end:
            live.stop()
    out["events"] = evs
    out["rig_fx"] = dev.rig().camera.fx
    out["queue_type"] = type(dev.pipe.camera_queue).__name__

    dev2 = OakDevice("CAM_B", t.W, t.H, 30.0, 200, pipeline_factory=factory)
    dev2.start()
    while dev2.camera.frames < 2:
        time.sleep(0.01)
    dev2.pipe.pipeline.stop()   # closes the queues under the readers, as an unplug does
    try:
        while True:
            dev2.camera.get(1.0)
    except DeviceError as exc:
        out["error"] = str(exc)
    print("RESULT " + json.dumps(out), flush=True)
    os._exit(0)
""")


def test_round_trip_through_real_depthai_queues() -> None:
    code = ROUND_TRIP.format(root=str(ROOT), tests=str(Path(__file__).parent))
    env = dict(os.environ, DEPTHAI_LEVEL="error")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env,
                          cwd=str(ROOT))
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert lines, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = json.loads(lines[0][7:])
    assert out["queue_type"] == "MessageQueue"
    evs = out["events"]
    frames = [e for e in evs if e[1]]
    assert len(frames) >= 10 and all(e[2] == [H, W] for e in frames)
    keys = [(e[0], int(e[1])) for e in evs]
    assert keys == sorted(keys) and len(evs) - len(frames) > 40
    assert frames[0][0] == T0 - EXPOSURE_US * 500  # device clock, mid-exposure
    assert out["rig_fx"] == pytest.approx(800.0 * W / 1280, rel=1e-6)
    assert re.search("(camera|imu) queue failed", out["error"]) and "MessageQueue was closed" in out["error"]


# -- calibration --------------------------------------------------------------------------------
def test_fixture_is_what_make_calibration_writes(tmp_path: Path) -> None:
    path = tmp_path / "c.json"
    make_calibration().eepromToJsonFile(str(path))
    assert json.loads(path.read_text()) == json.loads(FIXTURE.read_text())


def test_read_oak_rig_intrinsics_distortion_units_and_direction(calib: dai.CalibrationHandler) -> None:
    rig = read_oak_rig(calib, "CAM_B", 640, 400, fps=30.0)
    cam = rig.camera
    assert cam.distortion_model == "radtan" and cam.size == (640, 400)
    np.testing.assert_allclose(cam.distortion, RADTAN5, rtol=1e-6)
    # depthai scales the calibration (1280x800) to the output: K * 0.5
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [400.0, 400.5, 320.25, 200.125], rtol=1e-6)
    assert rig.time_offset_s == 0.0 and rig.camera_rate_hz == 30.0 and rig.imu is None
    # T_IC in metres (depthai's default unit is cm), and through depthai's own chain
    # IMU -> CAM_C -> CAM_B: equals the ground truth only if each stored link maps x_src to x_dst
    np.testing.assert_allclose(rig.T_IC, T_IB_TRUE, atol=2e-6)
    assert np.linalg.norm(rig.p_IC) < 0.2
    raw = np.array(calib.getImuToCameraExtrinsics(dai.CameraBoardSocket.CAM_B, False, dai.LengthUnit.METER))
    np.testing.assert_allclose(np.linalg.inv(raw), rig.T_IC, atol=2e-6)  # T_IC = inverse of depthai's
    # the other reading (each stored link = pose of dst in src, x_src = M x_dst): written that way,
    # depthai's chain gives a matrix that is neither T_IB nor T_BI, so depthai composes in x_dst = M x_src
    S = dai.CameraBoardSocket
    other = make_calibration()
    B_C, I_C = np.linalg.inv(T_CcB), np.linalg.inv(T_CcI)
    other.setCameraExtrinsics(S.CAM_B, S.CAM_C, B_C[:3, :3].tolist(), (B_C[:3, 3] * 100).tolist())
    other.setImuExtrinsics(S.CAM_C, I_C[:3, :3].tolist(), (I_C[:3, 3] * 100).tolist())
    chained = np.array(other.getImuToCameraExtrinsics(S.CAM_B, False, dai.LengthUnit.METER))
    for candidate in (chained, np.linalg.inv(chained)):
        assert not np.allclose(candidate, T_IB_TRUE, atol=1e-3)
    # directly linked camera: fisheye -> equidistant, and the same T_IC convention
    rig_c = read_oak_rig(calib, "CAM_C", 1280, 800)
    assert rig_c.camera.distortion_model == "equidistant"
    np.testing.assert_allclose(rig_c.camera.distortion, EQUI4, rtol=1e-6)
    np.testing.assert_allclose(rig_c.T_IC, np.linalg.inv(T_CcI), atol=2e-6)


def _device_transformation(size: tuple[int, int], out: tuple[int, int], K: list) -> dai.ImgTransformation:
    """depthai's own ImgTransformation of a centred crop of `size` to the output's aspect ratio (whole
    pixels), scaled to `out`: what the Camera node's CROP does."""
    (W, H), (w, h) = size, out
    s = max(w / W, h / H)
    cw, ch = min(W, round(w / s)), min(H, round(h / s))
    t = dai.ImgTransformation(W, H, K)
    t.addCrop((W - cw) // 2, (H - ch) // 2, cw, ch)
    t.addScale(w / cw, h / ch)
    assert tuple(t.getSize()) == (w, h)
    return t


@pytest.mark.parametrize("out", [(640, 400), (640, 480), (320, 240), (1280, 720), (800, 800)])
def test_intrinsics_are_those_of_the_cropped_output(calib: dai.CalibrationHandler, out) -> None:
    """The rig's K at an output size is what depthai's own transformation maths gives for the Camera node's
    centred crop and scale (getCameraIntrinsics pads a 4:3 output of the 16:10 calibration instead)."""
    rig = read_oak_rig(calib, "CAM_B", *out)
    expected = np.array(_device_transformation((1280, 800), out, K_MONO).getIntrinsicMatrix())
    np.testing.assert_allclose(rig.camera.K, expected, rtol=1e-6, atol=1e-6)
    if out == (640, 480):
        padded = np.array(calib.getCameraIntrinsics(dai.CameraBoardSocket.CAM_B, 640, 480))
        assert padded[0, 0] == pytest.approx(400.0) and rig.camera.fx == pytest.approx(480.0, rel=1e-3)


def test_the_first_frames_own_intrinsics_are_reported_and_compared_with_the_rig(calib) -> None:
    """A frame carries depthai's K of the delivered image: the camera's report keeps it, and notes when it
    differs from the rig's (the factory calibration read for another crop than the device made)."""
    for device_size, noted in (((W, H), False), ((W, 48), True)):
        dev, cq, _, _ = fake_device(calibration=calib)
        f = img_frame(0, 33_333_333)
        t = _device_transformation((1280, 800), device_size, K_MONO)
        if device_size != (W, H):                     # the device cropped to another aspect, then to W x H
            t.addCrop(0, (device_size[1] - H) // 2, W, H)
        f.setTransformation(t)
        cq.put(f)
        with dev:
            rig = dev.rig()
            assert dev.camera.get(2.0) is not None
            rep = dev.camera.report()
        np.testing.assert_allclose(rep["device_K"], t.getIntrinsicMatrix(), atol=1e-9)
        notes = [n for n in rep["notes"] if "own intrinsics" in n]
        assert bool(notes) == noted, notes
        if noted:
            assert f"fx {rig.camera.fx:.1f}" in notes[0] and "--rig" in notes[0]


def test_read_oak_rig_reads_the_rational_model_and_refuses_thin_prism(calib: dai.CalibrationHandler) -> None:
    """A factory calibration in OpenCV's rational model (CAM_A) becomes a rational camera whose projection
    is OpenCV's with the eight coefficients; thin-prism terms are refused with the reason."""
    import cv2

    from calib import PinholeRational

    rig = read_oak_rig(calib, "CAM_A", 640, 360)
    cam = rig.camera
    assert isinstance(cam, PinholeRational) and cam.distortion.tolist() == pytest.approx(RATIONAL[:8])
    p = np.random.default_rng(0).uniform([-0.5, -0.3, 1.0], [0.5, 0.3, 1.0], (100, 3))
    uv_cv = cv2.projectPoints(p, np.zeros(3), np.zeros(3), cam.K, cam.distortion)[0].reshape(-1, 2)
    np.testing.assert_allclose(cam.project(p), uv_cv, atol=1e-6)
    prism = make_calibration()
    prism.setDistortionCoefficients(dai.CameraBoardSocket.CAM_A, RATIONAL[:8] + [0.01, 0, 0, 0, 0, 0])
    with pytest.raises(CalibrationError, match=r"CAM_A.*thin-prism.*s1=0\.01.*Kalibr"):
        read_oak_rig(prism, "CAM_A", 640, 360)


def test_read_oak_rig_radtan4_and_missing_imu() -> None:
    c = dai.CalibrationHandler()
    S = dai.CameraBoardSocket
    c.setCameraIntrinsics(S.CAM_B, K_MONO, 1280, 800)
    c.setCameraType(S.CAM_B, dai.CameraModel.Perspective)
    c.setDistortionCoefficients(S.CAM_B, RADTAN5[:4] + [0.0] * 10)
    rig = read_oak_rig(c, "CAM_B", 1280, 800)
    assert rig.camera.distortion.size == 4 and rig.T_IC is None
    with pytest.raises(CalibrationError, match="IMU calibration data is not available"):
        read_oak_rig(c, "CAM_B", 1280, 800, require_extrinsics=True)


@pytest.mark.parametrize("R", [[[0.0] * 3] * 3, [[1.0, 0, 0], [0, 1.0, 0], [0, 0, -1.0]],
                               [[5.0, 1.0, 0], [0, 0.1, 0], [0, 0, 0]]],
                         ids=["zeroed", "reflection", "garbage"])
def test_corrupt_factory_extrinsics_are_withheld_and_said_not_made_a_rotation(tmp_path: Path, R) -> None:
    """The nearest rotation of a zeroed, reflected or garbage matrix is a made-up T_IC the run would trust
    (the bring-up skipped); it is withheld (the bring-up estimates it) and said."""
    data = json.loads(FIXTURE.read_text())
    data["imuExtrinsics"]["rotationMatrix"] = R
    path = tmp_path / "eeprom.json"
    path.write_text(json.dumps(data))
    c = dai.CalibrationHandler(str(path))
    notes: list[str] = []
    rig = read_oak_rig(c, "CAM_B", 640, 400, notes=notes)
    assert rig.T_IC is None and rig.camera is not None
    assert len(notes) == 1 and "the factory IMU-camera extrinsics are not a rigid transform" in notes[0]
    assert "bring-up estimates them" in notes[0] and "--rig" in notes[0]
    with pytest.raises(CalibrationError, match="not a rigid transform"):
        read_oak_rig(c, "CAM_B", 640, 400, require_extrinsics=True)
    dev, _, _, _ = fake_device(calibration=c)        # and in the camera's report (report.json, the notes)
    dev.open()
    try:
        assert dev.rig().T_IC is None
        assert any("not a rigid transform" in n for n in dev.camera.report()["notes"])
    finally:
        dev.stop()
    assert read_oak_rig(dai.CalibrationHandler(str(FIXTURE)), "CAM_B", 640, 400, notes=notes).T_IC is not None
    assert len(notes) == 1                     # the factory's own float32 rotation is taken as it is


def test_an_unreadable_calibration_says_why_and_what_to_pass() -> None:
    dev = OakDevice("CAM_B", W, H, 30.0, 200, pipeline_factory=lambda d: OakPipeline(
        FakeQueue(), FakeQueue(), FakePipe(), None, "OAK fake",
        calibration_problem="EEPROM read failed (test)"))
    dev.open()
    try:
        with pytest.raises(CalibrationError) as info:
            dev.rig()
    finally:
        dev.stop()
    msg = str(info.value)
    assert msg == ("OAK fake: no calibration read from the device (EEPROM read failed (test)); pass the "
                   "camera's calibration with --rig FILE (a Kalibr camchain)")


def test_gravity_at_rest_tells_the_direction(calib: dai.CalibrationHandler) -> None:
    """Synthetic rest recording through the driver: the camera (CAM_B) held level, image upright,
    so up is -y in camera coordinates and the accelerometer reads g along R_IB @ up_B."""
    dev, _, iq, _ = fake_device(calibration=calib)
    up_B = np.array([0.0, -1.0, 0.0])
    g_I = G * (T_IB_TRUE[:3, :3] @ up_B)
    rng = np.random.default_rng(3)
    for b in range(5):
        ts = [T0 + (10 * b + k) * 5_000_000 for k in range(10)]
        d = dai.IMUData()
        pkts = []
        for x in ts:
            p = dai.IMUPacket()
            p.acceleroMeter = report(dai.IMUReportAccelerometer, x, tuple(g_I + rng.normal(0, 0.05, 3)))
            p.gyroscope = report(dai.IMUReportGyroscope, x, tuple(rng.normal(0, 0.002, 3)))
            pkts.append(p)
        d.packets = pkts
        iq.put(d)
    with dev:
        wait_until(lambda: dev.imu.enqueued == 50)
        acc = np.mean([dev.imu.get(0.1).accel for _ in range(50)], axis=0)
        rig = dev.rig()
    res = check_extrinsics_direction(rig.T_IC, acc)
    assert res["verdict"] == "as_given" and res["angle_as_given_deg"] < 1.0
    assert res["angle_inverse_deg"] > 30.0
    assert check_extrinsics_direction(np.linalg.inv(rig.T_IC), acc)["verdict"] == "inverse"
    assert check_extrinsics_direction(rig.T_IC, -acc)["verdict"] == "neither"
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # a 180 degree turn: its own inverse
    assert check_extrinsics_direction(flip, flip[:3, :3] @ up_B)["verdict"] == "ambiguous"


def test_timedelta_ns_exact() -> None:
    assert timedelta_ns(dt.timedelta(days=2, seconds=3, microseconds=7)) == (2 * 86400 + 3) * 10**9 + 7000
    assert timedelta_ns(dt.timedelta(microseconds=-1)) == -1000


def test_module_imports_depthai_lazily() -> None:
    code = "import sys, drivers.oak; print('depthai' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=str(ROOT),
                         timeout=30)
    assert out.stdout.strip() == "False", out.stderr


if __name__ == "__main__":  # regenerate the calibration fixture
    FIXTURE.parent.mkdir(parents=True, exist_ok=True)
    make_calibration().eepromToJsonFile(str(FIXTURE))
    print(f"wrote {FIXTURE}")
