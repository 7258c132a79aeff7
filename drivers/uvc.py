"""A UVC camera (or a video file) read with OpenCV on its own thread (notes/drivers.md §3).

One reader thread only grabs, stamps, converts to grey and enqueues; the consumer takes frames with
`get(timeout)`. The buffer keeps the newest `keep_frames` frames and counts the older ones it drops.

Stamps (int64 ns on the host's `time.monotonic_ns()` clock), minus half the exposure time when it is
known (`exposure_s`), i.e. an estimate of mid-exposure:
- a V4L2 device (Linux): the kernel's buffer stamp (`CAP_PROP_POS_MSEC`: uvcvideo stamps a frame when its
  first packet arrives, on CLOCK_MONOTONIC, the clock of `time.monotonic_ns()`). It does not depend on
  when the reader thread gets to `grab()`: OpenCV's V4L2 backend queues a few buffers and `grab()` takes
  the oldest, so after a stall several frames would otherwise be stamped at nearly the same moment. A
  kernel stamp that is not between `KERNEL_STAMP_MAX_AGE_S` before the grab and the grab (another clock,
  or none) is replaced by the host stamp below and counted (`host_stamped`);
- otherwise (other backends, `kernel_stamps=False`): the host time right after `grab()` returns. It is
  late by a roughly constant latency (readout + transfer, a few ms to a frame period) and jitters with
  the thread's wake-up.
The constant part of either is what the camera-IMU time offset of the calibration (Kalibr
`timeshift_cam_imu`) and the filter's online estimate absorb. A stamp that does not increase (clock
jitter, a frame delivered twice) is dropped and counted.

A video file (replay, tests) is read the same way. With `realtime=True` frames are paced at the
file's rate and the newest-frames buffer behaves as for a camera; with `realtime=False` the reader
waits for the consumer, so nothing is dropped. `file_stamps=True` stamps frame i exactly
`start_ns + round(i * 1e9 / fps)` (fps: the `fps` argument, else the file's), which tests compare
exactly; otherwise files get host stamps like a camera.

Errors: a device that does not exist or does not open, a size other than `expected_size`, a read
failure (unplugged) or a stall (no frame for `stall_timeout_s`) are `runtime.errors.DeviceError`
with one line naming the device; `start()` raises the first two, `get()` raises the others once
the frames already buffered have been taken (`.error` holds them as soon as they happen).
"""
from __future__ import annotations

import os
import re
import stat
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from drivers.images import BitDepthScaler
from drivers.kept_frames import KeptFrames
from runtime.errors import DavioError, DeviceError
from runtime.events import Frame

NEVER = 2**63 - 1
"""A stamp later than any frame (the floor of a source that will deliver nothing more)."""

_POLL_S = 0.05
"""How often a waiting `get` re-checks for a stall."""
KERNEL_STAMP_MAX_AGE_S = 0.5
"""Oldest a V4L2 buffer stamp may be at `grab()` (frames queued while the reader was late) to be used."""


def kernel_stamp_ns(pos_msec: float, grab_ns: int, max_age_ns: int = int(KERNEL_STAMP_MAX_AGE_S * 1e9)
                    ) -> int | None:
    """The V4L2 buffer stamp `CAP_PROP_POS_MSEC` (ms on CLOCK_MONOTONIC) as int64 ns, or None when it is not
    on the clock of `grab_ns` (host monotonic right after the grab): later than the grab, older than
    `max_age_ns`, zero, negative or not finite."""
    if not (pos_msec == pos_msec and 0.0 < pos_msec < 9.2e15):       # NaN, none, or beyond int64 ns
        return None
    t = int(round(pos_msec * 1e6))
    return t if grab_ns - max_age_ns <= t <= grab_ns else None


class UvcCamera(KeptFrames):
    """A UVC camera (device index, device path or stream URL) or a video file, read on a thread.

    Args:
        device: camera index (0 = /dev/video0), a device path, a stream URL, or a video file.
        width, height, fps: requested mode (devices only; `fps` also overrides a file's rate).
            The camera may deliver another size: it is used as delivered (see `expected_size`).
        exposure_s: the exposure time in force, when known. On a V4L2 device it is also requested
            (manual exposure); the stamps are moved back by half of it (mid-exposure).
        stall_timeout_s: a live camera delivering no frame for this long is an error (unplugged).
        keep_frames: how many of the newest frames wait for the consumer; older ones are dropped.
        expected_size: (width, height) the images must have (e.g. the calibration's); another
            delivered size makes `start()` raise a DeviceError naming both.
        realtime: a video file is paced at its frame rate (as a live camera would deliver it).
        file_stamps: a video file's frames are stamped start + index / fps (exact, reproducible).
        bit_depth: bits of data in 16-bit images (10, 12, 14, 16; larger values are clipped and counted);
            None: set by the first image, raised by a later one holding larger values (noted).
        fourcc: a pixel format to request from a device (e.g. "MJPG"), or None for its default.
        camera_id: the `Frame.camera_id` of the frames.
        open_timeout_s: how long `start()` waits for the device to open (then for a first frame
            `open_timeout_s + stall_timeout_s` more).
        kernel_stamps: stamp a V4L2 device's frames with the kernel's buffer stamps (see the module
            docstring); False: the host time after `grab()` always.
    """

    def __init__(self, device: int | str, width: int | None = None, height: int | None = None,
                 fps: float | None = None, exposure_s: float | None = None, stall_timeout_s: float = 2.0,
                 keep_frames: int = 2, expected_size: tuple[int, int] | None = None,
                 realtime: bool = False, file_stamps: bool = False, bit_depth: int | None = None,
                 fourcc: str | None = None, camera_id: int = 0, open_timeout_s: float = 3.0,
                 kernel_stamps: bool = True) -> None:
        if isinstance(device, bool) or not isinstance(device, int | str | os.PathLike):
            raise DeviceError(f"camera device must be an index, a path or a video file, not {device!r}")
        if keep_frames < 1:
            raise DeviceError(f"camera {device}: keep_frames must be >= 1, not {keep_frames}")
        if stall_timeout_s <= 0:
            raise DeviceError(f"camera {device}: stall_timeout_s must be > 0, not {stall_timeout_s}")
        if fps is not None and not fps > 0:
            raise DeviceError(f"camera {device}: fps must be > 0, not {fps}")
        if exposure_s is not None and not exposure_s >= 0:
            raise DeviceError(f"camera {device}: exposure_s must be >= 0, not {exposure_s}")
        if bit_depth is not None and bit_depth not in (8, 10, 12, 14, 16):
            raise DeviceError(f"camera {device}: bit_depth must be 8, 10, 12, 14 or 16, not {bit_depth}")
        self.device = os.fspath(device) if isinstance(device, os.PathLike) else device
        self.width, self.height, self.fps = width, height, fps
        self.exposure_s = exposure_s
        self.stall_timeout_s = float(stall_timeout_s)
        self.keep_frames = int(keep_frames)
        self.expected_size = None if expected_size is None else (int(expected_size[0]), int(expected_size[1]))
        self.realtime, self.file_stamps = bool(realtime), bool(file_stamps)
        self.bit_depth = bit_depth
        self.fourcc = fourcc
        self.camera_id = int(camera_id)
        self.open_timeout_s = float(open_timeout_s)
        self.is_file = self._is_video_file(self.device)
        self.kernel_stamps = bool(kernel_stamps) and not self.is_file
        """Use the V4L2 buffer stamps (decided once the device is open: a V4L2 device; never a file, whose
        "buffer stamp" is its playback position)."""
        self.host_stamped = 0
        """Frames of a kernel-stamped device whose buffer stamp was unusable (stamped on the host)."""
        self._half_exposure_ns = 0 if exposure_s is None else int(round(exposure_s * 0.5e9))

        self._cond = threading.Condition()
        self._buf: deque[Frame] = deque()
        self._thread: threading.Thread | None = None
        self._opened = threading.Event()
        self._ready = threading.Event()
        self._stop = False
        self._eof = False
        self._error: DavioError | None = None
        self._start_error: DavioError | None = None
        self._floor_ns = -NEVER
        self._alive_ns = 0
        self.start_ns: int | None = None
        """Host time the stamps of a file start from (`file_stamps`), set by `start()`."""
        self.file_fps: float | None = None
        """The rate a file is paced and stamped at (the `fps` argument, else the file's)."""
        self.size: tuple[int, int] | None = None
        """(width, height) of the delivered images, known once `start()` returned."""
        self.backend: str | None = None
        self.fps_reported: float | None = None
        self.frames = 0
        self.emitted = 0
        self.dropped_old = 0
        self.nonmonotonic = 0
        self.converted = 0
        self.conversion: str | None = None
        self._scaler = BitDepthScaler(bit_depth)
        self.notes: list[str] = []
        self._first_t: int | None = None
        self._last_t: int | None = None

    # -- public -----------------------------------------------------------------------------------
    def start(self) -> UvcCamera:
        """Open the device and start the reader; returns once the first frame arrived.

        Raises DeviceError (one line, naming the device) when it does not exist, cannot be opened
        within `open_timeout_s`, delivers no frame, or delivers a size other than `expected_size`, or
        after `stop()` (nothing would stop it again). Idempotent."""
        if self._thread is not None:
            return self
        if self._stop:
            raise DeviceError(f"camera {self.device}: start() after stop()")
        self._check_exists()
        self._thread = threading.Thread(target=self._run, name=f"davio-uvc-{self.device}", daemon=True)
        self._thread.start()
        if not self._opened.wait(self.open_timeout_s):
            self._abandon()
            raise DeviceError(f"camera {self.device}: did not open within {self.open_timeout_s:g} s")
        if self._start_error is None and not self._ready.wait(self.open_timeout_s + self.stall_timeout_s):
            self._abandon()
            raise DeviceError(f"camera {self.device}: opened but delivered no frame within "
                              f"{self.open_timeout_s + self.stall_timeout_s:g} s")
        if self._start_error is not None:
            self._abandon()
            raise self._start_error
        return self

    def get(self, timeout: float | None = None) -> Frame | None:
        """The oldest kept frame, waiting up to `timeout` s (None: until one comes).

        Returns None on timeout, at the end of a video file (`.ended` is then True) or once
        stopped. Raises the DeviceError of a read failure or stall once the buffer is drained."""
        deadline = None if timeout is None else time.monotonic() + max(0.0, float(timeout))
        with self._cond:
            while True:
                if self._stop:
                    return None
                if self._buf:
                    frame = self._buf.popleft()
                    self.emitted += 1
                    self._cond.notify_all()
                    return frame
                err = self._check_error_locked()
                if err is not None:
                    raise err
                if self._eof:
                    return None
                wait = _POLL_S if deadline is None else min(_POLL_S, deadline - time.monotonic())
                if wait <= 0:
                    return None
                self._cond.wait(wait)

    @property
    def error(self) -> DavioError | None:
        """The read failure or stall that ended the stream (None while it is healthy)."""
        with self._cond:
            return self._check_error_locked()

    @property
    def ended(self) -> bool:
        """True once a video file is exhausted and every frame has been taken."""
        with self._cond:
            return self._eof and not self._buf

    def min_future_ns(self) -> int:
        """A lower bound of the stamp of every frame `get` will still return (buffered or not yet
        grabbed); `NEVER` once nothing more will come. Lets a consumer release IMU samples up to it
        without breaking time order."""
        with self._cond:
            if self._buf:
                return self._buf[0].t_ns
            if self._stop or self._eof or self._error is not None:
                return NEVER
            return self._floor_ns

    def stop(self) -> None:
        """Stop the reader and release the device (idempotent; waits up to 1 s for a blocked grab,
        after which the reader releases the device when its grab returns)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=1.0)

    close = stop

    def __enter__(self) -> UvcCamera:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def report(self) -> dict[str, Any]:
        """Counters: frames (kept after stamping), emitted (taken by `get`), dropped_old (pushed out
        of the buffer), nonmonotonic (dropped stamps), converted, size, rates, notes."""
        err = self.error
        fps_m = self.fps_measured()
        return {
            "device": str(self.device), "kind": "file" if self.is_file else "device", "backend": self.backend,
            "frames": self.frames, "emitted": self.emitted, "dropped_old": self.dropped_old,
            "nonmonotonic": self.nonmonotonic, "converted": self.converted, "conversion": self.conversion,
            "clipped_images": self._scaler.clipped_images,
            "host_stamped": self.host_stamped,
            "size": None if self.size is None else list(self.size),
            "requested_size": (None if self.width is None and self.height is None
                               else [self.width, self.height]),
            "expected_size": None if self.expected_size is None else list(self.expected_size),
            "fps_requested": self.fps, "fps_reported": self.fps_reported,
            "fps_measured": None if fps_m is None else round(fps_m, 3),
            "exposure_s": self.exposure_s, "keep_frames": self.keep_frames,
            "stamps": self._stamp_description(),
            "ended": self.ended, "error": None if err is None else str(err), "notes": list(self.notes),
        }

    # -- opening ----------------------------------------------------------------------------------
    @staticmethod
    def _is_video_file(device: int | str) -> bool:
        if not isinstance(device, str) or "://" in device:
            return False
        try:
            return stat.S_ISREG(os.stat(device).st_mode)
        except OSError:
            return False

    def _check_exists(self) -> None:
        """Fail fast, before OpenCV, on a path or index that names nothing."""
        dev = self.device
        if isinstance(dev, str):
            if "://" in dev or self.is_file:
                return
            if not os.path.exists(dev):
                what = "camera device" if dev.startswith("/dev/") else "camera device or video file"
                raise DeviceError(f"camera {dev}: no such {what}")
            if os.path.isdir(dev):
                raise DeviceError(f"camera {dev}: is a directory, not a camera device or video file")
        elif (sys.platform.startswith("linux") and os.path.isdir("/dev")
              and not Path(f"/dev/video{dev}").exists()):
            present = sorted(p.name for p in Path("/dev").glob("video*"))
            raise DeviceError(f"camera {dev}: no /dev/video{dev} (video devices present: "
                              f"{', '.join(present) if present else 'none'})")

    def _open(self, cv2: Any) -> Any:
        dev = self.device
        target, api = dev, cv2.CAP_ANY
        if not self.is_file and sys.platform.startswith("linux"):
            if isinstance(dev, str) and dev.startswith("/dev/"):
                # OpenCV's V4L2 backend opens by index only: /dev/video2 or a by-id link to it -> 2
                m = re.fullmatch(r"/dev/video(\d+)", os.path.realpath(dev))
                target = int(m.group(1)) if m else dev
            if isinstance(target, int):
                api = cv2.CAP_V4L2
        cap = cv2.VideoCapture(target, api)
        if not cap.isOpened():
            cap.release()
            if self.is_file:
                raise DeviceError(f"camera {dev}: the video file cannot be decoded by OpenCV")
            raise DeviceError(f"camera {dev}: cannot be opened (in use by another program, no permission "
                              f"(video group?), or not a capture device)")
        return cap

    def _configure(self, cv2: Any, cap: Any) -> None:
        try:
            self.backend = cap.getBackendName()
        except cv2.error:
            self.backend = None
        reported = cap.get(cv2.CAP_PROP_FPS)
        if self.is_file:
            self.fps_reported = float(reported) if reported > 0 else None
            self.file_fps = self.fps or self.fps_reported
            if (self.realtime or self.file_stamps) and not self.file_fps:
                raise DeviceError(f"camera {self.device}: the video file has no frame rate; pass fps")
            if self.width is not None or self.height is not None:
                self.notes.append("width/height are not applied to a video file")
            return
        if self.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*self.fourcc[:4].ljust(4)))
        if self.width is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, float(self.width))
        if self.height is not None:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, float(self.height))
        if self.fps is not None:
            cap.set(cv2.CAP_PROP_FPS, float(self.fps))
        self.kernel_stamps = self.kernel_stamps and self.backend == "V4L2"
        if self.exposure_s is not None and self.backend == "V4L2":
            # V4L2: auto_exposure 1 = manual; exposure_time_absolute in units of 100 us
            cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1.0)
            cap.set(cv2.CAP_PROP_EXPOSURE, float(self.exposure_s * 1e4))
            got = cap.get(cv2.CAP_PROP_EXPOSURE)
            if abs(got - self.exposure_s * 1e4) > max(1.0, 0.05 * self.exposure_s * 1e4):
                self.notes.append(f"exposure {self.exposure_s * 1e3:g} ms requested, the device reports "
                                  f"{got / 10:g} ms: stamps still use {self.exposure_s * 1e3:g} ms")
        reported = cap.get(cv2.CAP_PROP_FPS)
        self.fps_reported = float(reported) if reported > 0 else None
        if self.fps is not None and self.fps_reported and abs(self.fps_reported - self.fps) > 0.01 * self.fps:
            self.notes.append(f"{self.fps:g} fps requested, the device reports {self.fps_reported:g} fps")

    # -- reader thread ----------------------------------------------------------------------------
    def _abandon(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()

    def _run(self) -> None:
        cap = None
        try:
            import cv2

            cap = self._open(cv2)
            self._configure(cv2, cap)
        except DavioError as exc:
            self._start_error = exc
        except Exception as exc:  # any OpenCV failure is a device error
            self._start_error = DeviceError(f"camera {self.device}: cannot be opened ({exc})")
        finally:
            self._opened.set()
        if self._start_error is not None:
            self._finish(cap)
            return
        try:
            self._read_loop(cap)
        except DavioError as exc:
            self._fail(exc)
        except Exception as exc:  # surface any reader failure to the consumer
            self._fail(DeviceError(f"camera {self.device}: reader failed: {type(exc).__name__}: {exc}"))
        finally:
            self._finish(cap)

    def _fail(self, exc: DavioError) -> None:
        if not self._ready.is_set():
            self._start_error = exc
        with self._cond:
            if self._error is None and not self._stop:
                self._error = exc
            self._cond.notify_all()

    def _finish(self, cap: Any) -> None:
        if cap is not None:
            try:
                cap.release()
            except Exception:  # releasing a failed device must not mask its error
                pass
        with self._cond:
            self._floor_ns = NEVER
            self._cond.notify_all()
        self._opened.set()
        self._ready.set()

    def _file_stamp(self, i: int) -> int:
        assert self.start_ns is not None and self.file_fps
        return self.start_ns + int(round(i * 1e9 / self.file_fps))

    def _read_loop(self, cap: Any) -> None:
        import cv2

        self.start_ns = time.monotonic_ns()
        self._alive_ns = self.start_ns
        i = 0
        while True:
            with self._cond:
                if self.is_file and not self.realtime:  # lossless replay: wait for the consumer
                    while len(self._buf) >= self.keep_frames and not self._stop:
                        self._cond.wait(_POLL_S)
                    self._alive_ns = time.monotonic_ns()
                if self._stop:
                    return
                if self.file_stamps and self.is_file:
                    self._floor_ns = self._file_stamp(i)
                else:  # a frame grabbed from now on is stamped later than this
                    self._floor_ns = self._live_floor()
            if self.is_file and self.realtime:
                self._pace(self.start_ns + int(round(i * 1e9 / self.file_fps)))
                if self._stop:
                    return
                if not self.file_stamps:
                    with self._cond:
                        self._floor_ns = self._live_floor()
            ok = cap.grab()
            t_host = time.monotonic_ns()
            if not ok:
                self._end_of_stream("grab() failed")
                return
            ok, image = cap.retrieve()
            if not ok or image is None:
                self._end_of_stream("retrieve() returned no image")
                return
            if self.file_stamps and self.is_file:
                t_ns = self._file_stamp(i)
            else:
                t_ns = t_host - self._half_exposure_ns
                if self.kernel_stamps:
                    t_k = kernel_stamp_ns(cap.get(cv2.CAP_PROP_POS_MSEC), t_host)
                    if t_k is None:
                        self.host_stamped += 1
                    else:
                        t_ns = t_k - self._half_exposure_ns
            i += 1
            self._alive_ns = t_host
            if self._last_t is not None and t_ns <= self._last_t:
                self.nonmonotonic += 1
                continue
            grey = self._to_grey(image)
            size = (int(grey.shape[1]), int(grey.shape[0]))
            if self.size is None:
                self._check_first_size(size)
            elif size != self.size:
                raise DeviceError(f"camera {self.device}: image size changed from "
                                  f"{self.size[0]}x{self.size[1]} to {size[0]}x{size[1]}")
            frame = Frame(t_ns, grey, self.camera_id, meta={"seq": i - 1, "grab_ns": t_host})
            with self._cond:
                if self._stop:
                    return
                self._keep_newest(frame)
            self._ready.set()

    def _pace(self, target_ns: int) -> None:
        while not self._stop:
            left = target_ns - time.monotonic_ns()
            if left <= 0:
                return
            time.sleep(min(left / 1e9, _POLL_S))

    def _end_of_stream(self, what: str) -> None:
        if self.is_file:
            with self._cond:
                self._eof = True
                self._cond.notify_all()
            if self.frames == 0 and not self._ready.is_set():
                self._start_error = DeviceError(
                    f"camera {self.device}: the video file holds no decodable frame")
            return
        raise DeviceError(f"camera {self.device}: read failed ({what}): unplugged or no longer streaming")

    def _check_first_size(self, size: tuple[int, int]) -> None:
        self.size = size
        w, h = size
        if self.expected_size is not None and size != self.expected_size:
            ew, eh = self.expected_size
            asked = ""
            if self.width is not None or self.height is not None:
                asked = f" ({self.width}x{self.height} requested)"
            raise DeviceError(f"camera {self.device}: delivers {w}x{h} images{asked} but {ew}x{eh} are "
                              f"expected (the calibration's size): request that size or use a calibration "
                              f"made at {w}x{h}")
        if not self.is_file and ((self.width is not None and self.width != w)
                                 or (self.height is not None and self.height != h)):
            self.notes.append(f"{self.width}x{self.height} requested, the camera delivers {w}x{h}")

    def _to_grey(self, image: np.ndarray) -> np.ndarray:
        """(H, W) uint8: colour to grey (BGR/BGRA as OpenCV delivers), 16-bit to 8-bit by bit depth."""
        import cv2

        img = np.asarray(image)
        what = []
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.ndim == 3 and img.shape[2] in (3, 4):
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
            what.append("colour to grey")
        elif img.ndim != 2:
            raise DeviceError(f"camera {self.device}: unsupported image layout {img.shape} {img.dtype}")
        if img.dtype == np.uint16:
            bits = self._scaler.bits
            img = self._scaler.convert(img)
            if bits is not None and self._scaler.bits != bits:
                where = f"frame {self.frames + 1}"
                self.notes.append(self._scaler.raise_note(f"camera {self.device}", where))
            self.bit_depth = self._scaler.bits
            what.append(f"16-bit holding {self.bit_depth}-bit data to 8 bits (>> {self.bit_depth - 8})")
        elif img.dtype != np.uint8:
            raise DeviceError(f"camera {self.device}: unsupported pixel type {img.dtype}")
        if what:
            self.converted += 1
            self.conversion = ", ".join(what)
        return np.ascontiguousarray(img)

    def _check_error_locked(self) -> DavioError | None:
        if self._error is None and not self._stop and not self._eof and not self.is_file \
                and self._ready.is_set() and self._thread is not None and self._start_error is None:
            idle_s = (time.monotonic_ns() - self._alive_ns) / 1e9
            if idle_s > self.stall_timeout_s:
                self._error = DeviceError(f"camera {self.device}: no frame for {idle_s:.1f} s "
                                          f"(stall_timeout_s {self.stall_timeout_s:g}): unplugged or stalled")
        return self._error

    def _live_floor(self) -> int:
        """A lower bound of the stamp of a frame grabbed from now on: the host time less half the exposure;
        with kernel stamps also less their largest age, and never below the last stamp (stamps increase)."""
        floor = time.monotonic_ns() - self._half_exposure_ns
        if self.kernel_stamps:
            floor -= int(KERNEL_STAMP_MAX_AGE_S * 1e9)
            if self._last_t is not None:
                floor = max(floor, self._last_t + 1)
        return floor

    def _stamp_description(self) -> str:
        if self.is_file and self.file_stamps:
            if not self.file_fps:           # the file did not open (start() raised)
                return "file: start + index / the file's rate (not known: the file was not opened)"
            return f"file: start + index / {self.file_fps:g} fps"
        if self.kernel_stamps:
            return ("V4L2 kernel buffer stamps (CLOCK_MONOTONIC)"
                    + (" minus half the exposure (mid-exposure estimate)" if self._half_exposure_ns else "")
                    + (f"; {self.host_stamped} frames host-stamped after grab() (unusable buffer stamp)"
                       if self.host_stamped else ""))
        if self._half_exposure_ns:
            return "host monotonic after grab() minus half the exposure (mid-exposure estimate)"
        return "host monotonic after grab() (exposure unknown: end of readout plus transfer latency)"
