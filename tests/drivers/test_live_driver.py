"""LiveDriver without hardware: a replayed MJPG video (paced, file stamps on the host clock) and a
fake 200 Hz IMU thread stamping on the same clock."""
from __future__ import annotations

import signal
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from drivers.base import Driver, StreamCounts
from drivers.live import LiveDriver
from drivers.uvc import UvcCamera
from runtime.errors import DataError, DeviceError
from runtime.events import Frame, ImuSample

cv2 = pytest.importorskip("cv2")

W, H, N, FPS = 64, 48, 30, 30.0
IMU_PERIOD_NS = 5_000_000  # 200 Hz


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("live") / "moving.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (W, H))
    for i in range(N):
        img = np.full((H, W, 3), 40, np.uint8)
        img[:, (2 * i) % (W - 8):(2 * i) % (W - 8) + 8] = 255
        writer.write(img)
    writer.release()
    return path


class FakeImu:
    """200 Hz samples stamped on time.monotonic_ns(), delivered `latency_s` after their stamp by a
    reader thread; `fail_after_s` sets `.error` (a DataError) then; `skew_ns` shifts every stamp."""

    def __init__(self, latency_s: float = 0.002, fail_after_s: float | None = None, skew_ns: int = 0) -> None:
        self.latency_ns = int(latency_s * 1e9)
        self.fail_after_s = fail_after_s
        self.skew_ns = skew_ns
        self.error: DataError | None = None
        self.cond = threading.Condition()
        self.buf: deque[ImuSample] = deque()
        self.stopped = False
        self.produced = 0
        self.thread: threading.Thread | None = None

    def start(self) -> None:
        self.t0 = time.monotonic_ns() - 50_000_000  # a little IMU history before the camera
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        k = 0
        while not self.stopped:
            t = self.t0 + k * IMU_PERIOD_NS
            wait = (t + self.latency_ns - time.monotonic_ns()) / 1e9
            if wait > 0:
                time.sleep(wait)
            if self.fail_after_s is not None and (time.monotonic_ns() - self.t0) / 1e9 > self.fail_after_s:
                with self.cond:
                    self.error = DataError("imu0: serial read failed (device unplugged)", "/dev/ttyFAKE")
                    self.cond.notify_all()
                return
            s = ImuSample(t + self.skew_ns, np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, 9.81]))
            with self.cond:
                self._push(s)
                self.produced += 1
                self.cond.notify_all()
            k += 1

    def _push(self, s: ImuSample) -> None:
        """Queue one sample (called with `cond` held)."""
        self.buf.append(s)

    def get(self, timeout: float | None = None) -> ImuSample | None:
        with self.cond:
            if not self.buf and not self.stopped and self.error is None and timeout:
                self.cond.wait(timeout)
            if self.buf and not self.stopped:
                return self.buf.popleft()
            return None

    def stop(self) -> None:
        self.stopped = True
        if self.thread is not None:
            self.thread.join(1.0)

    def report(self) -> dict:
        return {"samples": self.produced, "notes": ["fake IMU"]}


def camera(video: Path, fps: float = FPS) -> UvcCamera:
    """The video paced on the host clock; its buffer holds every frame, so a consumer the machine's load
    delays loses none (the newest-kept policy is tested in test_uvc)."""
    return UvcCamera(video, fps=fps, realtime=True, file_stamps=True, keep_frames=N)


def check_order(events: list) -> None:
    """Non-decreasing stamps, the IMU first at equal stamps."""
    keys = [(e.t_ns, 0 if isinstance(e, ImuSample) else 1) for e in events]
    assert keys == sorted(keys)


def test_events_ordered_and_every_frame_preceded_by_its_imu(video: Path) -> None:
    imu = FakeImu()
    drv = LiveDriver(camera(video), imu, rig=None, imu_wait_s=5.0)  # no frame goes ahead on a loaded machine
    assert isinstance(drv, Driver) and drv.rig is None
    with drv:
        events = list(drv.events())
    assert drv.ended
    check_order(events)
    frames = [i for i, e in enumerate(events) if isinstance(e, Frame)]
    assert len(frames) == N
    for i in frames:
        f = events[i]
        before = [e for e in events[:i] if isinstance(e, ImuSample)]
        after = [e for e in events[i + 1:] if isinstance(e, ImuSample)]
        assert before and f.t_ns - before[-1].t_ns < IMU_PERIOD_NS  # the IMU up to its stamp came first
        if i != frames[-1]:
            assert after and after[0].t_ns > f.t_ns
    imus = [e for e in events if isinstance(e, ImuSample)]
    assert np.all(np.diff([e.t_ns for e in imus]) == IMU_PERIOD_NS)  # nothing lost
    rep = drv.report()
    assert rep["driver"] == "live" and set(rep["streams"]) == {"cam0", "imu0"}
    cam0 = StreamCounts(**rep["streams"]["cam0"])
    imu0 = StreamCounts(**rep["streams"]["imu0"])
    assert cam0.emitted == N and cam0.rows_accounted()
    assert cam0.median_period_ns == pytest.approx(1e9 / FPS, abs=1)
    assert imu0.emitted == len(imus) and imu0.rows_accounted() and imu0.median_period_ns == IMU_PERIOD_NS
    assert rep["live"]["frames_ahead_of_imu"] == 0 and rep["live"]["frames_before_imu"] == 0
    assert rep["sources"]["camera"]["frames"] == N and "imu0: fake IMU" in rep["notes"]


def test_positive_time_offset_waits_for_imu_past_the_frame(video: Path) -> None:
    imu = FakeImu()
    drv = LiveDriver(camera(video, fps=60.0), imu, time_offset_s=0.02, imu_wait_s=5.0)
    with drv:
        events = list(drv.events())
    check_order(events)
    frames = [e for e in events if isinstance(e, Frame)]
    assert len(frames) == N and drv.frames_ahead_of_imu == 0
    # the frame stamps are not shifted
    assert frames[1].t_ns - frames[0].t_ns == round(1e9 / 60.0)


def test_late_imu_frames_go_ahead_after_imu_wait(video: Path) -> None:
    imu = FakeImu(latency_s=0.15)  # the IMU arrives 150 ms late: longer than imu_wait_s
    drv = LiveDriver(camera(video, fps=60.0), imu, imu_wait_s=0.05)
    with drv:
        events = list(drv.events())
    check_order(events)
    rep = drv.report()
    assert rep["live"]["frames_ahead_of_imu"] > 0
    dropped = rep["streams"]["imu0"]["dropped_nonmonotonic"]
    assert dropped > 0  # samples older than released frames
    assert any("before the IMU reached" in n for n in rep["notes"])
    # the dropped samples leave holes in the IMU the filter gets: each is flagged on the next sample kept
    imus = [e for e in events if isinstance(e, ImuSample)]
    flagged = [k for k, e in enumerate(imus) if e.lost_before]
    assert flagged and 0 < sum(imus[k].lost_before for k in flagged) <= dropped
    assert rep["live"]["imu_lost_flagged"] == sum(imus[k].lost_before for k in flagged)
    for k in flagged:
        assert imus[k].t_ns - imus[k - 1].t_ns == (imus[k].lost_before + 1) * IMU_PERIOD_NS


def test_stop_from_another_thread_ends_events_promptly(video: Path) -> None:
    imu = FakeImu()
    cam = UvcCamera(video, fps=10.0, realtime=True, file_stamps=True)  # 3 s of video
    drv = LiveDriver(cam, imu).start()
    seen: list = []
    after_stop = 0
    stopped = threading.Event()

    def stopper() -> None:
        time.sleep(0.4)
        drv.stop()
        stopped.set()

    threading.Thread(target=stopper, daemon=True).start()
    for ev in drv.events():
        seen.append(ev)
        after_stop += stopped.is_set()
    # events() ended on the stop, not at the video's end; at most the event already handed over when
    # stop() returned arrives after it
    assert stopped.is_set() and after_stop <= 1
    assert any(isinstance(e, Frame) for e in seen) and not drv.ended
    assert sum(isinstance(e, Frame) for e in seen) < N
    check_order(seen)
    assert imu.stopped and cam.get(0.01) is None
    drv.stop()  # idempotent


def test_imu_error_surfaces_from_events(video: Path) -> None:
    imu = FakeImu(fail_after_s=0.3)
    drv = LiveDriver(camera(video), imu)
    seen: list = []
    with pytest.raises(DataError, match="serial read failed"), drv:
        for ev in drv.events():
            seen.append(ev)
    # the error (at 0.3 s) ended the stream before the 1 s video did
    assert seen and isinstance(drv.error, DataError) and not drv.ended
    assert sum(isinstance(e, Frame) for e in seen) < N
    assert "serial read failed" in drv.report()["live"]["error"]
    assert imu.stopped


def test_camera_start_failure_stops_the_imu(tmp_path: Path) -> None:
    imu = FakeImu()
    drv = LiveDriver(UvcCamera(str(tmp_path / "missing.avi")), imu)
    with pytest.raises(DeviceError, match="no such"):
        drv.start()
    assert imu.stopped


def test_a_driver_stopped_before_it_started_starts_nothing(video: Path) -> None:
    """The commands hand the driver out unstarted and stop it on every way out: a stop that comes first
    (Ctrl-C while the run is set up) leaves the sources unstarted, and nothing can start them after it."""
    imu = FakeImu()
    camera = UvcCamera(str(video), realtime=True)
    drv = LiveDriver(camera, imu)
    drv.stop()
    assert list(drv.events()) == [] and imu.thread is None
    with pytest.raises(DeviceError, match=r"start\(\) after stop\(\)"):
        drv.start()
    assert imu.thread is None and camera.report()["frames"] == 0


class ListSource:
    """A source replaying a fixed list, then ended (no thread)."""

    def __init__(self, items: list) -> None:
        self.items = deque(items)
        self.error = None

    def get(self, timeout: float | None = None):
        return self.items.popleft() if self.items else None

    @property
    def ended(self) -> bool:
        return not self.items

    def min_future_ns(self) -> int:
        return self.items[0].t_ns if self.items else 2**63 - 1

    def stop(self) -> None:
        pass


def test_out_of_order_input_is_dropped_and_counted() -> None:
    def s(t: int) -> ImuSample:
        return ImuSample(t, np.zeros(3), np.zeros(3))

    def f(t: int) -> Frame:
        return Frame(t, np.zeros((2, 2), np.uint8))

    imu = ListSource([s(t) for t in (0, 10, 20, 20, 15, 30, 40, 50, 60)])
    cam = ListSource([f(25), f(25), f(22), f(45)])
    drv = LiveDriver(cam, imu, imu_wait_s=0.0)
    events = list(drv.events())
    check_order(events)
    assert [(type(e).__name__[0], e.t_ns) for e in events] == [
        ("I", 0), ("I", 10), ("I", 20), ("F", 25), ("I", 30), ("I", 40), ("F", 45), ("I", 50), ("I", 60)]
    rep = drv.report()
    imu0, cam0 = rep["streams"]["imu0"], rep["streams"]["cam0"]
    assert imu0["dropped_duplicate"] == 1 and imu0["dropped_nonmonotonic"] == 1 and imu0["emitted"] == 7
    assert cam0["dropped_nonmonotonic"] == 2 and cam0["emitted"] == 2 and drv.ended


class FailingCamera(ListSource):
    """Delivers its frames, then reports an unplugged device (get raises once drained, like UvcCamera)."""

    def get(self, timeout: float | None = None):
        if self.items:
            return self.items.popleft()
        raise DeviceError("camera 0: read failed (grab() failed): unplugged or no longer streaming")

    @property
    def ended(self) -> bool:
        return False


def test_camera_error_surfaces_from_events() -> None:
    imu = FakeImu()
    now = time.monotonic_ns()
    cam = FailingCamera([Frame(now + k * 10_000_000, np.zeros((2, 2), np.uint8)) for k in range(3)])
    drv = LiveDriver(cam, imu)
    seen: list = []
    with pytest.raises(DeviceError, match="unplugged"):
        for ev in drv.events():
            seen.append(ev)
    assert sum(isinstance(e, Frame) for e in seen) == 3 and imu.stopped
    assert "unplugged" in drv.report()["live"]["error"]


@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs POSIX interval timers")
def test_stop_from_a_signal_handler(video: Path) -> None:
    imu = FakeImu()
    cam = UvcCamera(video, fps=10.0, realtime=True, file_stamps=True)
    drv = LiveDriver(cam, imu).start()
    fired: list[bool] = []

    def handler(signum, frame) -> None:
        drv.stop()
        fired.append(True)

    old = signal.signal(signal.SIGALRM, handler)
    n = after_stop = 0
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.3)
        for _ in drv.events():
            n += 1
            after_stop += bool(fired)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    # the handler runs between two events: the generator yields nothing once stop() returned
    assert fired and after_stop == 0 and n > 0 and not drv.ended
    assert imu.stopped and cam.get(0.01) is None


class OverflowingImu(FakeImu):
    """FakeImu whose bounded queue holds `capacity` samples: when the consumer is late, the oldest go and
    are counted for `take_overflow()`, as the serial and OAK IMU sources do."""

    def __init__(self, capacity: int) -> None:
        super().__init__()
        self.capacity = capacity
        self.lost = 0
        self.pending = 0
        self.dropped_stamps: list[int] = []

    def _push(self, s: ImuSample) -> None:
        if len(self.buf) >= self.capacity:
            self.dropped_stamps.append(self.buf.popleft().t_ns)
            self.lost += 1
            self.pending += 1
        self.buf.append(s)

    def take_overflow(self) -> int:
        with self.cond:
            n, self.pending = self.pending, 0
            return n

    def report(self) -> dict:
        return {"samples": self.produced, "overflow": self.lost}


def test_imu_overflow_is_flagged_on_the_next_sample_delivered(video: Path) -> None:
    imu = OverflowingImu(capacity=4)
    drv = LiveDriver(camera(video), imu)
    with drv:
        it = drv.events()
        events = [next(it)]
        time.sleep(0.2)                         # the consumer stalls: 40 samples arrive, 4 fit
        events += list(it)
    imus = [e for e in events if isinstance(e, ImuSample)]
    flagged = [e for e in imus if e.lost_before]
    assert imu.lost > 20 and sum(e.lost_before for e in imus) == imu.lost
    for e in flagged:                           # every flagged sample follows the samples it lost
        k = imus.index(e)
        lost_here = [t for t in imu.dropped_stamps if (imus[k - 1].t_ns if k else 0) < t < e.t_ns]
        assert len(lost_here) == e.lost_before
    rep = drv.report()
    assert rep["live"]["imu_lost_flagged"] == imu.lost
    notes = rep["notes"]
    assert f"imu0: {imu.lost} samples lost to the IMU queue's overflow (the consumer fell behind)" in notes
    assert f"imu0: {imu.lost} lost samples flagged to the filter as gaps (on the sample after them)" in notes


class LossyImu(FakeImu):
    """A FakeImu whose own report counts what a serial parser drops before the merge."""

    def report(self) -> dict:
        return {"samples": self.produced, "nonfinite": 13, "seq_gaps": 13, "checksum_errors": 0,
                "bytes_skipped": 2, "notes": []}


def test_losses_inside_a_source_reach_the_notes(video: Path) -> None:
    drv = LiveDriver(camera(video), LossyImu(), rig=None)
    with drv:
        list(drv.events())
    notes = drv.report()["notes"]
    assert ("imu0: lost in the driver: 13 samples with NaN or Inf values dropped, 13 gaps in the device's "
            "sequence counter, 2 bytes skipped to resynchronise") in notes
    assert not any(n.startswith("cam0: lost") for n in notes)
