"""UvcCamera without hardware: a small MJPG video written with OpenCV, and a fake capture device."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.uvc import NEVER, UvcCamera
from runtime.errors import DavioError, DeviceError

cv2 = pytest.importorskip("cv2")

W, H, N, FPS = 64, 48, 30, 30.0


def write_video(path: Path, n: int = N, fps: float = FPS, size: tuple[int, int] = (W, H)) -> Path:
    """A colour MJPG .avi of a bar moving right, `n` frames."""
    w, h = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    assert writer.isOpened()
    for i in range(n):
        img = np.full((h, w, 3), 40, np.uint8)
        x = (2 * i) % (w - 8)
        img[:, x:x + 8] = (255, 200, 30)
        writer.write(img)
    writer.release()
    return path


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_video(tmp_path_factory.mktemp("uvc") / "moving.avi")


def drain(cam: UvcCamera, timeout: float = 2.0) -> list:
    frames = []
    while (f := cam.get(timeout)) is not None:
        frames.append(f)
    return frames


def test_file_frames_grey_sized_counted_with_exact_stamps(video: Path) -> None:
    with UvcCamera(str(video), file_stamps=True) as cam:
        frames = drain(cam)
        assert cam.ended
        assert cam.get(0.01) is None
        rep = cam.report()
    assert len(frames) == N
    for i, f in enumerate(frames):
        assert f.image.dtype == np.uint8 and f.image.shape == (H, W) and f.camera_id == 0
        assert f.t_ns == cam.start_ns + round(i * 1e9 / FPS)
        assert f.meta["seq"] == i
    # the bar moves 2 px a frame: its centroid follows
    for i, f in enumerate(frames[:10]):
        weight = np.clip(f.image.mean(axis=0) - 80.0, 0.0, None)
        centre = float((np.arange(W) * weight).sum() / weight.sum())
        assert centre == pytest.approx(2 * i + 3.5, abs=1.0)
    assert rep["frames"] == rep["emitted"] == N
    assert rep["dropped_old"] == 0 and rep["nonmonotonic"] == 0
    assert rep["size"] == [W, H] and rep["kind"] == "file"
    assert rep["fps_measured"] == pytest.approx(FPS, rel=1e-3)
    assert rep["converted"] == N and "grey" in rep["conversion"]
    assert cam.min_future_ns() == NEVER


def test_file_realtime_paced_and_fps_override(video: Path) -> None:
    cam = UvcCamera(video, fps=60.0, realtime=True, file_stamps=True).start()
    t0 = time.monotonic()
    frames = drain(cam)
    took = time.monotonic() - t0
    cam.stop()
    assert len(frames) == N
    assert took > 0.35  # paced: 30 frames at 60 fps take 0.5 s
    assert frames[1].t_ns - frames[0].t_ns == round(1e9 / 60.0)
    # each frame is delivered no earlier than its stamp (paced on the host clock)
    assert all(f.meta["grab_ns"] >= f.t_ns for f in frames)


def test_file_realtime_slow_consumer_keeps_newest(video: Path) -> None:
    cam = UvcCamera(video, fps=100.0, realtime=True, file_stamps=True, keep_frames=2).start()
    time.sleep(0.5)  # the whole file (0.3 s) passes while nobody reads
    frames = drain(cam)
    cam.stop()
    rep = cam.report()
    assert [f.meta["seq"] for f in frames] == [N - 2, N - 1]
    assert rep["dropped_old"] == N - 2 and rep["frames"] == N


def test_host_stamps_increase_and_exposure_moves_them_back(video: Path) -> None:
    cam = UvcCamera(video, exposure_s=0.01).start()
    frames = drain(cam)
    cam.stop()
    assert len(frames) + cam.nonmonotonic == N
    t = [f.t_ns for f in frames]
    assert all(b > a for a, b in zip(t, t[1:], strict=False))
    assert all(f.meta["grab_ns"] - f.t_ns == 5_000_000 for f in frames)
    assert "mid-exposure" in cam.report()["stamps"]


def test_expected_size_mismatch_names_both_sizes(video: Path) -> None:
    # the first frame's size fails start() at once, not the wait for a first frame
    with pytest.raises(DeviceError, match=r"delivers 64x48.*640x480"):
        UvcCamera(video, expected_size=(640, 480), open_timeout_s=60.0).start()
    UvcCamera(video, expected_size=(W, H)).start().stop()


@pytest.mark.parametrize("device", ["/dev/video97", "/no/such/video.avi", 97])
def test_missing_device_fails_fast_and_clearly(device: int | str) -> None:
    cam = UvcCamera(device, open_timeout_s=60.0)
    with pytest.raises(DeviceError, match="no /dev/video97|no such") as info:
        cam.start()
    assert cam._thread is None  # refused before OpenCV opens anything (no wait for a device)
    assert "\n" not in str(info.value) and str(device) in str(info.value)


def test_undecodable_file_and_directory(tmp_path: Path) -> None:
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"not a video" * 100)
    with pytest.raises(DeviceError, match="cannot be decoded"):
        UvcCamera(bad).start()
    with pytest.raises(DeviceError, match="directory"):
        UvcCamera(str(tmp_path)).start()


def test_a_paced_file_is_host_stamped_not_taken_for_a_kernel_clock(video: Path, tmp_path: Path) -> None:
    """As `davio live uvc --camera FILE` opens it: every frame was counted as an unusable V4L2 buffer
    stamp (its playback position read as one) and the report named the kernel clock."""
    cam = UvcCamera(video, fps=200.0, realtime=True).start()
    frames = drain(cam)
    rep = cam.report()
    cam.stop()
    assert frames and rep["host_stamped"] == 0 and rep["stamps"].startswith("host monotonic after grab()")
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"not a video" * 100)
    failed = UvcCamera(bad, file_stamps=True)
    with pytest.raises(DeviceError, match="cannot be decoded"):
        failed.start()
    assert "not known" in failed.report()["stamps"]          # report() after a failed start raised


def test_stop_is_idempotent_and_get_after_stop(video: Path) -> None:
    cam = UvcCamera(video, realtime=True, file_stamps=True).start()
    assert cam.get(1.0) is not None
    cam.stop()
    cam.stop()
    assert cam.get(0.1) is None
    UvcCamera(video).stop()  # never started
    stopped = UvcCamera(video)
    stopped.stop()           # a stop first (e.g. from another thread while LiveDriver starts its sources)
    with pytest.raises(DeviceError, match=r"start\(\) after stop\(\)"):
        stopped.start()      # would run a reader that nothing stops
    assert stopped.report()["frames"] == 0


# -- a fake capture device: colour/16-bit conversion, unplug and stall -------------------------------
class FakeCapture:
    """Stands in for cv2.VideoCapture on a device: `script` yields images, None = read failure,
    "block" = grab() hangs (a stalled camera)."""

    script: list = []
    period_s = 0.005

    def __init__(self, target, api=None) -> None:
        self.items = iter(type(self).script)
        self.image = None
        self.released = threading.Event()
        self.props: dict[int, float] = {}

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return True

    def getBackendName(self) -> str:  # noqa: N802
        return "FAKE"

    def set(self, prop: int, value: float) -> bool:
        self.props[prop] = value
        return True

    def get(self, prop: int) -> float:
        return self.props.get(prop, 0.0)

    def grab(self) -> bool:
        time.sleep(self.period_s)
        item = next(self.items, None)
        if isinstance(item, str):
            self.released.wait(5.0)
            return False
        self.image = item
        return item is not None

    def retrieve(self):
        return True, self.image

    def release(self) -> None:
        self.released.set()


@pytest.fixture
def fake_cv2(monkeypatch: pytest.MonkeyPatch) -> type[FakeCapture]:
    monkeypatch.setattr(cv2, "VideoCapture", FakeCapture)
    return FakeCapture


def test_fake_device_16bit_and_colour_conversion(fake_cv2: type[FakeCapture]) -> None:
    img16 = np.full((H, W), 4095, np.uint16)  # 12-bit data in 16-bit pixels
    img16[0, 0] = 16
    fake_cv2.script = [img16, img16] + [None]
    cam = UvcCamera("fake://cam", width=W, height=H, stall_timeout_s=1.0).start()
    f = cam.get(1.0)
    assert f is not None and f.image.dtype == np.uint8 and f.image.shape == (H, W)
    assert f.image[1, 1] == 255 and f.image[0, 0] == 1  # >> 4
    assert "12-bit" in cam.report()["conversion"]
    cam.stop()


def test_fake_device_dark_first_16bit_frame_does_not_clip_the_next(fake_cv2: type[FakeCapture]) -> None:
    dark = np.full((H, W), 100, np.uint16)          # auto-exposure settling: 8-bit values in the first
    bright = np.full((H, W), 4000, np.uint16)       # then 12-bit data
    fake_cv2.script = [dark, bright] + [None]
    cam = UvcCamera("fake://cam", width=W, height=H, stall_timeout_s=1.0, keep_frames=4).start()
    first, second = cam.get(1.0), cam.get(1.0)
    assert first.image[0, 0] == 100 and second.image[0, 0] == 4000 >> 4      # not clipped to 255
    rep = cam.report()
    assert "12-bit" in rep["conversion"] and any("frame 2 holds 12-bit data" in n for n in rep["notes"])
    assert rep["clipped_images"] == 0
    cam.stop()


def test_fake_device_read_failure_raises_after_drain(fake_cv2: type[FakeCapture]) -> None:
    colour = np.zeros((H, W, 3), np.uint8)
    fake_cv2.script = [colour] * 3 + [None]
    cam = UvcCamera("fake://cam", keep_frames=5).start()
    deadline = time.monotonic() + 2.0
    while cam.error is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert isinstance(cam.error, DeviceError) and "unplugged" in str(cam.error)
    got = [cam.get(0.1) for _ in range(3)]  # the frames read before the failure still come
    assert all(g is not None for g in got)
    with pytest.raises(DeviceError, match="read failed"):
        cam.get(0.1)
    cam.stop()


def test_fake_device_stall_is_an_error(fake_cv2: type[FakeCapture]) -> None:
    fake_cv2.script = [np.zeros((H, W), np.uint8)] * 2 + ["block"]
    cam = UvcCamera("fake://cam", stall_timeout_s=0.3).start()
    with pytest.raises(DeviceError, match=r"no frame for .*stall_timeout_s 0\.3"):
        while True:
            cam.get(0.1)
    assert isinstance(cam.error, DavioError)
    cam.stop()  # returns although the grab stays blocked (the reader is abandoned)


def test_fake_device_size_mismatch_and_requested_size_note(fake_cv2: type[FakeCapture]) -> None:
    fake_cv2.script = [np.zeros((H, W), np.uint8)] * 50
    with pytest.raises(DeviceError, match=r"delivers 64x48 images \(640x480 requested\) but 640x480"):
        UvcCamera("fake://cam", width=640, height=480, expected_size=(640, 480)).start()
    cam = UvcCamera("fake://cam", width=640, height=480).start()
    assert cam.size == (W, H)
    assert any("640x480 requested" in n for n in cam.report()["notes"])
    cam.stop()


class FakeV4l2(FakeCapture):
    """A V4L2 device whose kernel stamps each buffer when its frame arrives, one `period_ns` apart, while
    the reader grabs them late and all at once (a stalled reader): `pos_ms` gives each buffer's stamp,
    None = a driver without stamps (0)."""

    period_ns = 33_333_333
    stamps: list = []

    def __init__(self, target, api=None) -> None:
        super().__init__(target, api)
        self.k = -1
        self.t0 = time.monotonic_ns() - 400_000_000        # the first frame arrived 0.4 s ago

    def getBackendName(self) -> str:  # noqa: N802
        return "V4L2"

    def grab(self) -> bool:
        self.k += 1
        return super().grab()

    def get(self, prop: int) -> float:
        if prop == cv2.CAP_PROP_POS_MSEC:
            kind = type(self).stamps[self.k] if self.k < len(type(self).stamps) else "ok"
            if kind == "none":
                return 0.0
            if kind == "realtime":                          # another clock: the wall clock
                return time.time() * 1e3
            return (self.t0 + self.k * self.period_ns) / 1e6
        return super().get(prop)


def _until_unplugged(cam: UvcCamera) -> list:
    """Every frame the camera delivers until its script's read failure (raised after the drain)."""
    out = []
    with pytest.raises(DeviceError, match="read failed"):
        while (f := cam.get(1.0)) is not None:
            out.append(f)
    return out


def test_kernel_stamp_is_used_only_on_the_grab_clock() -> None:
    from drivers.uvc import kernel_stamp_ns

    grab = 10**12
    assert kernel_stamp_ns((grab - 30_000_000) / 1e6, grab) == grab - 30_000_000
    assert kernel_stamp_ns((grab + 1_000_000) / 1e6, grab) is None        # after the grab
    assert kernel_stamp_ns((grab - 600_000_000) / 1e6, grab) is None      # older than 0.5 s
    assert kernel_stamp_ns(0.0, grab) is None and kernel_stamp_ns(float("nan"), grab) is None
    assert kernel_stamp_ns(-5.0, grab) is None


def test_v4l2_frames_carry_the_kernels_stamps_not_the_grab_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """Frames queued in the kernel while the reader was late keep their arrival stamps (one period apart,
    minus half the exposure), though grabbed together; a buffer without a usable stamp (none, or another
    clock) is stamped on the host and counted; a file or kernel_stamps=False keeps host stamps."""
    monkeypatch.setattr(cv2, "VideoCapture", FakeV4l2)
    monkeypatch.setattr(UvcCamera, "_check_exists", lambda self: None)
    img = np.full((H, W), 100, np.uint8)
    FakeV4l2.script = [img] * 8 + [None]
    FakeV4l2.period_s = 0.0                                    # grabbed all at once
    FakeV4l2.stamps = ["ok"] * 6 + ["none", "realtime"]
    cam = UvcCamera(0, exposure_s=0.01, stall_timeout_s=1.0, keep_frames=16).start()
    frames = _until_unplugged(cam)
    rep = cam.report()
    cam.stop()
    assert [f.meta["seq"] for f in frames] == list(range(8))
    t0 = frames[0].t_ns + 5_000_000                           # + half the exposure: the first buffer's stamp
    for f in frames[:6]:                              # grabbed within microseconds, stamped 33 ms apart
        assert f.t_ns == t0 + f.meta["seq"] * FakeV4l2.period_ns - 5_000_000
    assert frames[5].meta["grab_ns"] - frames[0].meta["grab_ns"] < FakeV4l2.period_ns
    for f in frames[6:]:                                      # no stamp, another clock: the host's
        assert f.t_ns == f.meta["grab_ns"] - 5_000_000
    assert rep["host_stamped"] == 2 and "V4L2 kernel buffer stamps" in rep["stamps"]
    FakeV4l2.stamps = []
    FakeV4l2.script = [img] * 3 + [None]
    host = UvcCamera(0, stall_timeout_s=1.0, kernel_stamps=False, keep_frames=8).start()
    got = _until_unplugged(host)
    host.stop()
    assert not host.kernel_stamps and got and all(f.t_ns >= f.meta["grab_ns"] for f in got)
