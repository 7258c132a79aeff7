"""A live driver: one camera and one IMU source merged into one time-ordered event stream.

The sources are duck-typed objects that run their own reader thread (notes/drivers.md §3):
`start()` (optional), `stop()`, `get(timeout) -> event | None`, `.error` (a DavioError or None),
optionally `.ended` (a replayed file is exhausted), `report() -> dict` and, for the camera,
`min_future_ns()` (a lower bound of the stamps of the frames still to come; `UvcCamera` has it).
Both must stamp on the same clock (host `time.monotonic_ns()`; a serial IMU maps its device clock
onto it).

Merging (`events()`), in non-decreasing t_ns order with the IMU first at equal stamps:
- IMU samples are released as soon as no frame still to come can be older than them, i.e. up to the
  camera's `min_future_ns()` (without it: up to now - `imu_wait_s`). With a camera stamped at
  mid-exposure they wait at most about one frame period plus the camera's latency.
- A frame is released once the IMU has reached its stamp + max(0, time_offset_s) (t_imu = t_cam +
  time_offset_s, Kalibr's convention: the filter then has the IMU it needs to propagate to it), after
  the IMU samples up to its stamp. The frame's stamp itself is not shifted: the pipeline applies the
  offset. If the IMU has not got there after `imu_wait_s` the frame is released anyway
  (`frames_ahead_of_imu`); if no IMU sample has arrived at all, it is dropped (`frames_before_imu`).
- Anything that would break the order (an IMU sample older than what was already released, a frame
  stamp that does not increase) is dropped and counted.
- Samples an IMU source lost to its queue's overflow (`take_overflow()`, optional) are flagged on the
  next sample it delivers (`ImuSample.lost_before`): the filter counts the gap and the feed-forward
  start-up never solves a window across it. So are the samples the merge drops as out of order (they
  came after a frame released ahead of them) and the flags such a dropped sample carried.
`events()` returns when `stop()` is called (from any thread or a signal handler; within about
`poll_s`), or when a source ends (the rest is flushed first). A source error is raised from
`events()` as that DavioError (anything else is wrapped in a DeviceError).
"""
from __future__ import annotations

import dataclasses
import statistics
import threading
import time
from collections import deque
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from drivers.base import Driver, IntakeReport
from runtime.errors import DavioError, DeviceError
from runtime.events import Frame, ImuSample

if TYPE_CHECKING:
    from calib import Rig

_IMU, _FRAME = 0, 1
"""Order keys: at equal stamps the IMU sample comes first."""

_PERIODS_KEPT = 512
"""Intervals kept per stream for the median period of the report."""


SOURCE_LOSSES = {
    "nonfinite": "samples with NaN or Inf values dropped",
    "duplicates": "packets repeating the previous one dropped",
    "backward_dropped": "samples whose device time went back dropped",
    "checksum_errors": "packets failing their checksum dropped",
    "malformed_packets": "malformed packets dropped",
    "missing_fields": "packets lacking a field dropped",
    "partial_packets": "partial packets dropped",
    "seq_gaps": "gaps in the device's sequence counter",
    "seq_skipped": "frames skipped in those gaps",
    "missing_estimated": "samples missing in those gaps (estimated)",
    "bytes_skipped": "bytes skipped to resynchronise",
}
"""Counters in a source's own report (serial IMU parser, OAK camera) of data lost before the merge; each
non-zero one becomes a note, so it reaches the console with the other input repairs."""


class LiveDriver(Driver):
    """A `Driver` over a live camera and a live IMU (e.g. `UvcCamera` and `SerialImu`).

    Args:
        camera: the frame source (`get(timeout) -> Frame | None`).
        imu: the IMU source (`get(timeout) -> ImuSample | None`).
        rig: the calibration, returned by `rig` (the driver does not use it).
        imu_wait_s: how long a frame waits for the IMU to reach its stamp before it goes anyway.
        time_offset_s: t_imu = t_cam + time_offset_s; a positive offset makes a frame wait for the
            IMU up to its stamp + offset (its stamp is not changed).
        poll_s: the longest a wait for the sources lasts (bounds how fast `stop()` is seen).
    """

    def __init__(self, camera: Any, imu: Any, rig: Rig | None = None, imu_wait_s: float = 0.1,
                 time_offset_s: float = 0.0, poll_s: float = 0.005) -> None:
        if not imu_wait_s >= 0:
            raise DeviceError(f"imu_wait_s must be >= 0, not {imu_wait_s}")
        if not poll_s > 0:
            raise DeviceError(f"poll_s must be > 0, not {poll_s}")
        self.camera, self.imu = camera, imu
        self._rig = rig
        self.imu_wait_s = float(imu_wait_s)
        self.time_offset_s = float(time_offset_s)
        self.poll_s = float(poll_s)
        self._wait_ns = int(round(self.imu_wait_s * 1e9))
        self._lead_ns = max(0, int(round(self.time_offset_s * 1e9)))
        self._started = False
        self._stop_requested = False
        self._sources_stopping = False
        self._sources_stopper: int | None = None
        self._sources_stopped = threading.Event()
        self._loop_thread: int | None = None
        self._in_loop = False
        self.ended = False
        """True once a source ended and `events()` returned after flushing."""
        self.error: DavioError | None = None
        """The source error `events()` raised, if any."""
        # counters
        self.cam_received = self.cam_emitted = self.cam_out_of_order = 0
        self.frames_ahead_of_imu = self.frames_before_imu = self.frames_after_imu_end = 0
        self.imu_received = self.imu_emitted = self.imu_out_of_order = self.imu_duplicate = 0
        self.imu_lost_flagged = 0
        self._periods: dict[str, deque[int]] = {"cam0": deque(maxlen=_PERIODS_KEPT),
                                                "imu0": deque(maxlen=_PERIODS_KEPT)}
        self._last_emitted: dict[str, int | None] = {"cam0": None, "imu0": None}

    # -- Driver --------------------------------------------------------------------------------
    @property
    def rig(self) -> Rig | None:
        """The rig given to the constructor (None when unknown)."""
        return self._rig

    def start(self) -> LiveDriver:
        """Start the IMU, then the camera (so the IMU covers the first frames). Idempotent.
        A camera that fails to start stops the IMU and raises its error. DeviceError after `stop()` (its
        sources would run with nothing left to stop them)."""
        if self._started:
            return self
        if self._stop_requested:
            raise DeviceError(f"{self._describe()}: start() after stop()")
        self._started = True
        try:
            for src in (self.imu, self.camera):
                start = getattr(src, "start", None)
                if callable(start):
                    start()
        except BaseException:
            self._stop_sources()
            raise
        return self

    def stop(self) -> None:
        """Make `events()` return (within about `poll_s`) and stop both sources. Idempotent; safe
        from another thread or a signal handler (inside `events()` on the same thread it only sets a
        flag, and `events()` stops the sources on its way out)."""
        self._stop_requested = True
        if self._in_loop and self._loop_thread == threading.get_ident():
            return
        self._stop_sources()

    def close(self) -> None:
        self.stop()
        super().close()

    def __enter__(self) -> LiveDriver:
        return self.start()

    def events(self) -> Iterator[ImuSample | Frame]:
        """The merged, time-ordered events (see the module docstring). Starts the sources if needed; none
        after `stop()` (the sources are not started then)."""
        if self._stop_requested:
            return
        self.start()
        self._loop_thread = threading.get_ident()
        self._in_loop = True
        try:
            yield from self._merge()
        except DavioError as exc:
            self.error = exc
            raise
        finally:
            self._in_loop = False
            self._stop_sources()

    def report(self) -> dict:
        """IntakeReport dict (driver "live", streams "cam0" and "imu0", notes) plus "live" (the merge's
        counters) and "sources" (each source's own report)."""
        cam_rep = _source_report(self.camera)
        imu_rep = _source_report(self.imu)
        rep = IntakeReport("live", self._describe(), policy="drop")
        cam = rep.stream("cam0")
        cam_nonmono = int(cam_rep.get("nonmonotonic", 0) or 0)
        cam.lines = self.cam_received + cam_nonmono
        cam.dropped_nonmonotonic = cam_nonmono + self.cam_out_of_order
        cam.parsed = cam.lines - cam.dropped
        cam.emitted = self.cam_emitted
        cam.converted = int(cam_rep.get("converted", 0) or 0)
        imu = rep.stream("imu0")
        imu.lines = self.imu_received
        imu.dropped_nonmonotonic = self.imu_out_of_order
        imu.dropped_duplicate = self.imu_duplicate
        imu.parsed = imu.lines - imu.dropped
        imu.emitted = self.imu_emitted
        for name, counts in (("cam0", cam), ("imu0", imu)):
            periods = list(self._periods[name])
            counts.median_period_ns = int(statistics.median(periods)) if periods else 0
        dropped_old = int(cam_rep.get("dropped_old", 0) or 0)
        if dropped_old:
            rep.note(f"cam0: {dropped_old} frames dropped by the camera's newest-frames buffer "
                     f"(the consumer fell behind the camera)")
        if cam_nonmono:
            rep.note(f"cam0: {cam_nonmono} frames with a stamp that did not increase were dropped")
        if self.frames_ahead_of_imu:
            rep.note(f"cam0: {self.frames_ahead_of_imu} frames released before the IMU reached their stamp "
                     f"(waited {self.imu_wait_s:g} s)")
        if self.frames_before_imu:
            rep.note(f"cam0: {self.frames_before_imu} frames dropped: no IMU sample had arrived yet")
        if self.frames_after_imu_end:
            rep.note(f"cam0: {self.frames_after_imu_end} frames after the end of the IMU stream were dropped")
        if self.cam_out_of_order:
            rep.note(f"cam0: {self.cam_out_of_order} frames older than events already released were dropped")
        if self.imu_out_of_order:
            rep.note(f"imu0: {self.imu_out_of_order} samples older than events already released were dropped "
                     f"(they came after a frame released ahead of them)")
        if self.imu_duplicate:
            rep.note(f"imu0: {self.imu_duplicate} samples repeating the previous stamp were dropped")
        overflow = int(imu_rep.get("overflow", 0) or 0)
        if overflow:
            rep.note(f"imu0: {overflow} samples lost to the IMU queue's overflow (the consumer fell behind)")
        if self.imu_lost_flagged:
            rep.note(f"imu0: {self.imu_lost_flagged} lost samples flagged to the filter as gaps (on the "
                     f"sample after them)")
        if cam.converted and cam_rep.get("conversion"):
            rep.note(f"cam0: images converted ({cam_rep['conversion']})")
        if cam_rep.get("clipped_images"):
            rep.note(f"cam0: {int(cam_rep['clipped_images'])} 16-bit images held values above the camera's "
                     "given bit depth: clipped to white")
        for name, sub in (("cam0", cam_rep), ("imu0", imu_rep)):
            losses = [f"{int(sub[key])} {text}" for key, text in SOURCE_LOSSES.items()
                      if isinstance(sub.get(key), int | float) and sub[key]]
            if losses:
                rep.note(f"{name}: lost in the driver: " + ", ".join(losses))
            for text in sub.get("notes") or []:
                rep.note(f"{name}: {text}")
            if sub.get("error"):
                rep.note(f"{name}: {sub['error']}")
        out = rep.as_dict()
        out["live"] = {"frames_ahead_of_imu": self.frames_ahead_of_imu,
                       "frames_before_imu": self.frames_before_imu,
                       "frames_after_imu_end": self.frames_after_imu_end,
                       "frames_dropped_by_camera_buffer": dropped_old,
                       "imu_lost_flagged": self.imu_lost_flagged,
                       "imu_wait_s": self.imu_wait_s, "time_offset_s": self.time_offset_s,
                       "ended": self.ended, "stopped": self._stop_requested,
                       "error": None if self.error is None else str(self.error)}
        out["sources"] = {"camera": cam_rep, "imu": imu_rep}
        return out

    # -- merging -------------------------------------------------------------------------------
    def _merge(self) -> Iterator[ImuSample | Frame]:
        cam, imu = self.camera, self.imu
        imu_buf: deque[ImuSample] = deque()
        pending: Frame | None = None
        pending_since = 0
        state = {"imu_newest": None, "last_key": None, "last_frame": None}
        floor_of = getattr(cam, "min_future_ns", None)
        cam_done = imu_done = False

        take_overflow = getattr(imu, "take_overflow", None)
        carried = [0]     # samples lost before the next kept one: overflow, dropped ones and their flags

        def accept_imu(s: ImuSample) -> None:
            self.imu_received += 1
            # the source dropped its oldest samples: they preceded this one
            carried[0] += int(take_overflow() or 0) if take_overflow is not None else 0
            t = int(s.t_ns)
            newest = state["imu_newest"]
            if newest is not None and t == newest:
                self.imu_duplicate += 1
                carried[0] += int(s.lost_before)
            elif (newest is not None and t < newest) or (
                    state["last_key"] is not None and (t, _IMU) < state["last_key"]):
                self.imu_out_of_order += 1
                carried[0] += int(s.lost_before) + 1
            else:
                if carried[0]:
                    s = dataclasses.replace(s, lost_before=int(s.lost_before) + carried[0])
                    self.imu_lost_flagged += carried[0]
                    carried[0] = 0
                imu_buf.append(s)
                state["imu_newest"] = t

        def emit(ev: ImuSample | Frame, key: tuple[int, int], stream: str) -> ImuSample | Frame:
            state["last_key"] = key
            last = self._last_emitted[stream]
            if last is not None:
                self._periods[stream].append(key[0] - last)
            self._last_emitted[stream] = key[0]
            if stream == "cam0":
                self.cam_emitted += 1
            else:
                self.imu_emitted += 1
            return ev

        def release_imu(upto: int) -> list[ImuSample | Frame]:
            out: list[ImuSample | Frame] = []
            while imu_buf and imu_buf[0].t_ns <= upto:
                s = imu_buf.popleft()
                out.append(emit(s, (int(s.t_ns), _IMU), "imu0"))
            return out

        def release_frame(f: Frame) -> list[ImuSample | Frame]:
            out = release_imu(int(f.t_ns))
            out.append(emit(f, (int(f.t_ns), _FRAME), "cam0"))
            return out

        while not self._stop_requested:
            out: list[ImuSample | Frame] = []
            # IMU: take what has arrived
            while not imu_done:
                s = self._get(imu, "imu0", 0.0)
                if s is None:
                    imu_done = bool(getattr(imu, "ended", False))
                    break
                accept_imu(s)
            # camera: one frame at a time
            f = None
            if pending is None and not cam_done:
                f = self._get(cam, "cam0", 0.0)
                if f is None:
                    cam_done = bool(getattr(cam, "ended", False))
                else:
                    self.cam_received += 1
                    t = int(f.t_ns)
                    if (state["last_frame"] is not None and t <= state["last_frame"]) or (
                            state["last_key"] is not None and (t, _FRAME) < state["last_key"]):
                        self.cam_out_of_order += 1
                    else:
                        pending, pending_since = f, time.monotonic_ns()
                        state["last_frame"] = t
            finishing = cam_done or (imu_done and pending is None and f is None)
            if pending is not None:
                newest = state["imu_newest"]
                if newest is not None and newest >= int(pending.t_ns) + self._lead_ns:
                    out += release_frame(pending)
                    pending = None
                elif imu_done:  # the IMU ended before this frame: nothing more can be placed
                    self.frames_after_imu_end += 1
                    pending, finishing = None, True
                elif time.monotonic_ns() - pending_since >= self._wait_ns:
                    if newest is None:
                        self.frames_before_imu += 1
                    else:
                        self.frames_ahead_of_imu += 1
                        out += release_frame(pending)
                    pending = None
            # IMU up to what no frame still to come can precede
            if pending is not None:
                floor = int(pending.t_ns)
            elif finishing:
                floor = 2**63 - 1
            elif floor_of is not None:
                floor = int(floor_of())
            else:
                floor = time.monotonic_ns() - self._wait_ns
            out += release_imu(floor)
            for ev in out:
                if self._stop_requested:
                    return
                self._in_loop = False
                yield ev
                self._in_loop = True
            if finishing:
                self.ended = True
                return
            if not out:
                self._idle_wait(accept_imu, imu_done)

    def _idle_wait(self, accept_imu: Any, imu_done: bool) -> None:
        """Wait up to `poll_s` for the next IMU sample (the most frequent event)."""
        t0 = time.monotonic()
        if not imu_done:
            s = self._get(self.imu, "imu0", self.poll_s)
            if s is not None:
                accept_imu(s)
                return
        left = self.poll_s - (time.monotonic() - t0)
        if left > 0.0005:  # a source whose get() does not block: do not spin
            time.sleep(left)

    @staticmethod
    def _get(src: Any, name: str, timeout: float) -> Any:
        try:
            ev = src.get(timeout)
        except DavioError:
            raise
        except Exception as exc:
            raise DeviceError(f"{name}: {type(exc).__name__}: {exc}") from exc
        if ev is None:
            err = getattr(src, "error", None)
            if err is not None:
                if isinstance(err, DavioError):
                    raise err
                raise DeviceError(f"{name}: {err}")
        return ev

    def _stop_sources(self) -> None:
        """Stop both sources once; a second caller on another thread waits (up to 2 s) until they are
        stopped. No lock is taken, so a signal handler can never deadlock on it."""
        if self._sources_stopping:
            if self._sources_stopper != threading.get_ident():
                self._sources_stopped.wait(2.0)
            return
        self._sources_stopping = True
        self._sources_stopper = threading.get_ident()
        try:
            for src in (self.imu, self.camera):
                stop = getattr(src, "stop", None)
                if callable(stop):
                    try:
                        stop()
                    except Exception:  # stopping one source must not keep the other running
                        pass
        finally:
            self._sources_stopped.set()

    def _describe(self) -> str:
        cam = getattr(self.camera, "device", None)
        imu = getattr(self.imu, "port", None) or getattr(self.imu, "device", None)
        return (f"camera {cam if cam is not None else type(self.camera).__name__} + "
                f"IMU {imu if imu is not None else type(self.imu).__name__}")


def _source_report(src: Any) -> dict:
    rep = getattr(src, "report", None)
    if not callable(rep):
        return {}
    try:
        out = rep()
    except Exception as exc:  # a report must not fail the run's report
        return {"error": f"report() failed: {exc}"}
    return out if isinstance(out, dict) else {"report": out}
