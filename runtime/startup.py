"""Start-up: buffered-replay handoff between the feed-forward initializer and the filter (Sec. IV-C).

Every measurement (IMU sample, feature-track set of a frame) goes into an 8 s buffer and to the
native filter, whose own initializers stay armed. An accepted feed-forward state (computed by the
model worker for a window that is already in the past) is written once into a *fresh* filter
through its initialization entry point; that candidate replays the buffered measurements after the
state's time faster than real time, then follows the live stream. It is selected once it produced
five consecutive states within 0.15 s of the live stream, abandoned if not selected within 3 s of
sensor time, and at most five candidates are tried. Whichever filter is ready first publishes; on the
same measurement the native filter wins (it is fed first), and the candidates still replaying are
dropped (counted as `candidates_outrun`). No measurement is dropped: a candidate whose replay start
left the buffer is refused and counted.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from runtime.config_checks import at_least, non_negative, positive
from runtime.errors import ConfigError
from runtime.events import Frame, ImuSample
from runtime.geometry.se3 import make_pose
from runtime.imu.stamps_back import StampsBehind
from runtime.msckf.init_common import InitResult
from runtime.startup_buffer import MeasurementBuffer, nearest_stamps
from runtime.startup_offset import OffsetFindings
from runtime.startup_resolves import ReSolves


@dataclass
class StartupConfig:
    """Start-up and handoff parameters (paper Sec. III and IV-C)."""

    buffer_s: float = 8.0
    """Seconds of measurements kept for replay."""
    catch_up_s: float = 0.15
    """A candidate's state counts as live when at most this far behind the newest frame."""
    consecutive_states: int = 5
    """Consecutive live states that select a candidate."""
    abandon_after_s: float = 3.0
    """Sensor seconds after which an unselected candidate is abandoned."""
    max_candidates: int = 5
    """Feed-forward candidates tried per start-up (reset after a divergence)."""
    replay_batch: int = 60
    """Buffered measurements a replaying candidate processes per live measurement."""
    window_images: int = 5
    window_spacing_s: float = 0.2
    """Start-up window: five images spaced 0.2 s."""
    window_tolerance_s: float = 0.03
    """Largest distance of a window image from its ideal time."""
    feedforward: bool = True
    """Use the feed-forward initializer."""
    extend_refused_s: float = 1.0
    """A window refused for too short a span (runtime.ffinit.extension.EXTENDABLE) is re-solved, without a
    model call, with the frames tracked after it (spaced about window_spacing_s, ending at the newest
    frame), again each spacing, while the newest frame is at most this many seconds past the window's last
    image (0: off). Meanwhile no new model window is requested. Measured from the window, not from the
    model's answer: a model slower than this never gets a re-solve."""
    native: bool = True
    """Keep the filter's own (static/dynamic) initializers armed."""
    time_offset_findings: int = 1
    """Feed-forward windows that must find the same camera-IMU time offset far from the one in use
    (runtime.ffinit.time_offset_check) before the start-up adopts it: later windows, the native filter and
    its initializers then use it (with ffinit.correct_time_offset). One: no window of a right rig found
    another offset in `davio bench rig-checks`, the native dynamic initializer would otherwise start (and
    diverge) with the wrong offset before a second window answers, and a later window that finds another
    offset relative to the adopted one adopts again..."""
    time_offset_agree_s: float = 0.01
    """...within this of each other (s); their mean is adopted. Candidates still replaying at an offset
    further than this from the adopted one are dropped."""

    def __post_init__(self) -> None:
        s = "startup"
        positive(self, s, "buffer_s", "abandon_after_s", "window_spacing_s", "time_offset_agree_s")
        non_negative(self, s, "catch_up_s", "window_tolerance_s", "extend_refused_s")
        at_least(self, s, 1, "consecutive_states", "max_candidates", "replay_batch", "time_offset_findings")
        at_least(self, s, 3, "window_images")
        if self.window_tolerance_s >= self.window_spacing_s / 2:
            raise ConfigError(f"startup.window_tolerance_s must be below half of startup.window_spacing_s "
                              f"({self.window_spacing_s / 2:g} s), got {self.window_tolerance_s}")


@dataclass
class Published:
    """A published IMU state in the odometry frame O (IMU clock t_ns; the frame's camera time)."""

    t_ns: int
    t_cam_ns: int
    R_OI: np.ndarray
    p_OI: np.ndarray
    v_OI: np.ndarray
    source: str
    filter_id: int
    segment: int = 0
    """Restarts after a divergence before this state: a new segment starts a new odometry frame."""
    covariance: np.ndarray | None = None
    """(6, 6) covariance of [rotation error (body frame), position] from the filter, or None."""

    @property
    def T_OI(self) -> np.ndarray:
        """(4,4) the IMU pose in the odometry frame."""
        return make_pose(self.R_OI, self.p_OI)


class Candidate:
    """A fresh filter booted from a feed-forward state, replaying the buffer to catch up."""

    def __init__(self, cid: int, filt: Any, init: InitResult, created_ns: int, start_seq: int) -> None:
        self.cid = cid
        self.filter = filt
        self.init = init
        self.created_ns = created_ns
        self.cursor = start_seq
        self.consecutive = 0
        self.status = "replaying"  # replaying | selected | abandoned | diverged | outrun | offset_dropped
        self.states_out = 0

    def step(self, buffer: MeasurementBuffer, limit: int | None) -> list:
        """Feed up to `limit` buffered measurements (None: all available); returns filter states."""
        out = []
        n = 0
        while self.cursor < buffer.next_seq and (limit is None or n < limit):
            e = buffer.get(self.cursor)
            self.cursor += 1
            n += 1
            if e.kind == "imu":
                out += self.filter.feed_imu(e.payload)
            else:
                t, ids, uv = e.payload
                out += self.filter.feed_tracks(t, ids, uv)
        self.states_out += len(out)
        return out


@dataclass
class StartupReport:
    """Counters and timings of the start-up (all in the run report)."""

    ff_requests: int = 0
    ff_accepted: int = 0
    ff_rejections: dict = field(default_factory=dict)
    ff_rejection_first: dict = field(default_factory=dict)
    """{reason: the first such rejection's detail} (what the counts alone do not say)."""
    candidates_started: int = 0
    candidates_selected: int = 0
    candidates_abandoned: int = 0
    candidates_refused_buffer: int = 0
    candidates_diverged: int = 0
    candidates_outrun: int = 0
    """Candidates still replaying when another filter was selected (they are dropped)."""
    candidates_offset_dropped: int = 0
    """Candidates still replaying at a time offset other than one the start-up adopted (dropped)."""
    ff_extensions: int = 0
    """Re-solves of refused windows over a longer span (no model call)."""
    ff_extension_accepted: int = 0
    """Re-solves that gave a state (not in ff_accepted, which counts model windows)."""
    ff_extension_rejections: dict = field(default_factory=dict)
    ff_extension_expired: int = 0
    """Refused windows whose extension reached extend_refused_s without an accepted state."""
    ff_time_offset_corrected: int = 0
    """Accepted windows solved at a camera-IMU time offset other than the one in use (runtime.ffinit.
    time_offset_check): the rig's offset is wrong."""
    ff_time_offset_first: str = ""
    """The first such window's finding."""
    ff_time_offset_s: float | None = None
    """The offset (t_imu = t_cam + offset, s) of the newest such window."""
    time_offset_findings: int = 0
    """Windows that found a camera-IMU time offset far from the one in use (accepted at it or refused)."""
    time_offset_first: str = ""
    """The first finding's detail (how far, which way, both fits)."""
    time_offset_adopted_s: float | None = None
    """The offset the start-up adopted from agreeing findings (None: the rig's kept)..."""
    time_offset_adopted_t_ns: int | None = None
    """...and when (the newest measurement's stamp then)."""
    ff_windows_imu_lost: int = 0
    """Feed-forward windows not solved: the live driver lost IMU samples inside them."""
    published_by: str | None = None
    """The filter publishing now (None after a reset, until another is selected)."""
    first_published_by: str | None = None
    """The filter that published the run's first state (kept through resets)."""
    first_publish_t_ns: int | None = None
    refused_before_first: dict = field(default_factory=dict)
    """The native initializers' refusals (counts by code, last reason) when the first state was published."""
    first_measurement_t_ns: int | None = None
    restarts_after_divergence: int = 0


class StartupManager:
    """Routes measurements to the native filter and feed-forward candidates; decides who publishes.

    Args:
        make_filter: builds a fresh filter (an MsckfEstimator with its native initializers armed
            when `native`) — called for the native filter and for every candidate.
        time_offset_s: t_imu = t_cam + time_offset_s (to place feed-forward windows on the IMU clock).
        imu_lead_s: IMU kept before a window's first image in the arrays handed to its solve (the time-offset
            check scans shifts towards earlier IMU times).
        adopt_time_offset: called with a camera-IMU time offset the feed-forward windows agree on
            (`StartupConfig.time_offset_findings`), after the start-up and its native filter took it up; None:
            findings are only counted.
    """

    def __init__(self, make_filter: Callable[[bool], Any], cfg: StartupConfig | None = None,
                 time_offset_s: float = 0.0, imu_lead_s: float = 0.02,
                 adopt_time_offset: Callable[[float], None] | None = None) -> None:
        self.cfg = cfg or StartupConfig()
        self.make_filter = make_filter
        self.offset_ns = int(round(time_offset_s * 1e9))
        self.imu_lead_ns = int(round(imu_lead_s * 1e9))
        self.adopt_time_offset = adopt_time_offset
        self.buffer = MeasurementBuffer(self.cfg.buffer_s)
        self.native = make_filter(self.cfg.native)
        self.candidates: list[Candidate] = []
        self.publisher: Any = None
        self.publisher_source = ""
        self.publisher_id = 0
        self.report = StartupReport()
        self._frames: deque[Frame] = deque(maxlen=64)
        self._newest_cam_ns: int | None = None
        self._newest_ns = 0
        gap_s = getattr(getattr(self.native, "config", None), "max_imu_gap_s", None)
        #: samples stamped behind the newest one (a clock that went back)
        self._behind = StampsBehind(int((0.05 if gap_s is None else gap_s) * 1e9))
        self._cid = 0
        self._tried = 0
        self._last_request_ns: int | None = None
        self._imu_loss_ns: deque[int] = deque(maxlen=256)
        outage_s = getattr(getattr(self.native, "config", None), "max_imu_outage_s", None)
        #: ns, a longer IMU gap is an outage no feed-forward window spans (msckf.max_imu_outage_s)
        self._outage_ns = None if outage_s is None else int(outage_s * 1e9)
        self._refused_window_ns: int | None = None
        self._resolves = ReSolves(self.cfg.extend_refused_s, self.cfg.window_spacing_s, self.report)
        self._offsets = OffsetFindings(self.cfg.time_offset_findings, self.cfg.time_offset_agree_s,
                                       self.report)

    # ------------------------------------------------------------------ measurements
    @property
    def published(self) -> bool:
        return self.publisher is not None

    def on_imu(self, sample: ImuSample) -> list[Published]:
        if self.report.first_measurement_t_ns is None:
            self.report.first_measurement_t_ns = int(sample.t_ns)
        t = int(sample.t_ns)
        behind = bool(self._newest_ns) and t <= self._newest_ns
        if behind:
            self._behind.behind(t)
        else:
            # a clock that went back B s passes the newest stamp B s later: an outage if that is long
            unseen_ns = t - self._newest_ns + self._behind.passed()
            if getattr(sample, "lost_before", 0) or (
                    self._newest_ns and self._outage_ns is not None and unseen_ns > self._outage_ns):
                self._imu_loss_ns.append(t)       # no feed-forward window spans a loss or an outage
            self._newest_ns = t
        if self.publisher is not None:
            return self._publish(self.publisher.feed_imu(sample))
        if not behind:     # a window must not mix the samples of a clock that went back with the newer ones
            self.buffer.append("imu", sample.t_ns, sample)
        out = self._publish_native(self.native.feed_imu(sample))
        return out + self._advance_candidates()

    def on_tracks(self, t_cam_ns: int, ids: np.ndarray, uv: np.ndarray,
                  frame: Frame | None = None) -> list[Published]:
        self._newest_cam_ns = int(t_cam_ns)
        if self.publisher is not None:
            return self._publish(self.publisher.feed_tracks(t_cam_ns, ids, uv))
        if frame is not None and self.cfg.feedforward:
            self._frames.append(frame)
        self.buffer.append("tracks", t_cam_ns, (int(t_cam_ns), ids, uv))
        out = self._publish_native(self.native.feed_tracks(t_cam_ns, ids, uv))
        if self.publisher is None:
            out += self._advance_candidates()
        keep = min((c.cursor for c in self.candidates), default=None)
        self.buffer.trim(self._newest_ns, keep)
        return out

    # ------------------------------------------------------------------ feed-forward
    def window(self) -> list[Frame] | None:
        """Five buffered frames spaced 0.2 s ending at the newest frame the IMU covers, or None.

        The IMU covers a frame once a sample reached its time on the IMU clock (t_cam + time offset): with a
        positive offset the newest frames wait for it, or no window would ever be covered. None also while
        that frame is less than one spacing after the newest frame of the last requested window: with a fast
        model, consecutive windows would share four of five images, and one request per event would starve
        tracking."""
        if self.publisher is not None or not self.cfg.feedforward or not self._frames:
            return None
        if self._tried >= self.cfg.max_candidates:
            return None
        frames = self._covered_frames()
        if not frames:
            return None
        spacing_ns = self.cfg.window_spacing_s * 1e9
        newest = int(frames[-1].t_ns)
        if self._last_request_ns is not None and newest - self._last_request_ns < 0.999 * spacing_ns:
            return None
        t = np.array([f.t_ns for f in frames], np.int64)
        ideal = [int(t[-1]) - int(round(k * spacing_ns)) for k in range(self.cfg.window_images - 1, -1, -1)]
        idx = nearest_stamps(t, ideal, self.cfg.window_tolerance_s)
        return None if idx is None else [frames[i] for i in idx]

    def _covered_frames(self) -> list[Frame]:
        """The buffered frames the IMU covers: a sample reached t_cam + time offset."""
        return [f for f in self._frames if int(f.t_ns) + self.offset_ns <= self._newest_ns]

    def imu_for(self, frames: list[Frame]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """IMU arrays covering the window on the IMU clock, or None if not yet covered or if IMU samples
        were lost inside it (counted once per window: preintegration across the loss would be wrong)."""
        return self.imu_between(int(frames[0].t_ns), int(frames[-1].t_ns))

    def imu_between(self, t0_cam_ns: int, t1_cam_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """imu_for between two camera stamps."""
        imu, lost = self._imu_span(t0_cam_ns, t1_cam_ns)
        t1 = int(t1_cam_ns) + self.offset_ns
        if lost and self._refused_window_ns != t1:
            self._refused_window_ns = t1
            self.report.ff_windows_imu_lost += 1
        return imu

    def _imu_span(self, t0_cam_ns: int, t1_cam_ns: int) -> tuple[tuple | None, bool]:
        """(IMU arrays covering the span, or None; whether samples were lost inside it). The arrays reach
        back `imu_lead_s` before the span, or to the newest loss there (a sample flagged `lost_before` starts
        an intact run), so that a loss before the span only shortens the lead."""
        t0 = int(t0_cam_ns) + self.offset_ns
        t1 = int(t1_cam_ns) + self.offset_ns
        lead = t0 - max(self.imu_lead_ns, 20_000_000)
        if any(t0 < lost <= t1 + 20_000_000 for lost in self._imu_loss_ns):
            return None, True
        lead = max([lead] + [lost for lost in self._imu_loss_ns if lead < lost <= t0])
        t, w, a = self.buffer.imu_arrays(lead, t1 + 20_000_000)
        if t.size < 2 or t[0] > t0 or t[-1] < t1:
            # none reached t1, and the next sample is flagged as following lost ones: the gap spans t1
            after = [lost for lost in self._imu_loss_ns if lost > t1]
            gap = bool(t.size) and t[-1] < t1 and bool(after) and \
                self.buffer.imu_arrays(int(t[-1]) + 1, min(after))[0].size == 1
            return None, gap
        return (t, w, a), False

    def extension_imu(self, stamps: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """IMU arrays for a re-solve over `stamps`, or None: not yet covered (the IMU lags the newest
        frame), or lost inside the span, which never heals: the re-solves are then given up (counted
        as extension_imu_lost, not as a lost model window)."""
        imu, lost = self._imu_span(stamps[0], stamps[-1])
        if lost:
            self.end_extension("extension_imu_lost")
        return imu

    def extension(self) -> tuple[Any, list[int]] | None:
        """(seed, stamps) of a due re-solve of the refused window over a longer span, or None.

        stamps: the window's images, then the frames after it spaced about one window spacing, ending at
        the newest frame (runtime.startup_resolves.ReSolves decides when one is due and when they end)."""
        if not self.extension_pending():
            return None
        t = np.array([f.t_ns for f in self._covered_frames()], np.int64)
        if not t.size:
            return None
        ideal = self._resolves.due_times(int(t[-1]))
        idx = None if ideal is None else nearest_stamps(t, ideal, self.cfg.window_tolerance_s)
        if idx is None:
            return None
        seed = self._resolves.seed
        return seed, [int(s) for s in seed.t_cam_ns] + [int(t[i]) for i in idx]

    def extension_pending(self) -> bool:
        """A refused window still waits for a longer re-solve (no new model window meanwhile)."""
        return self._resolves.seed is not None and self.publisher is None \
            and self._tried < self.cfg.max_candidates

    def end_extension(self, reason: str) -> None:
        """Give up the re-solves of the refused window (counted under `reason`), e.g. when its tracks
        left the buffer; model windows are requested again."""
        self._resolves.end(reason)

    def note_extension(self, stamps: list[int]) -> None:
        """Count a re-solve over `stamps` (the next waits one spacing after its newest frame)."""
        self._resolves.note(stamps)

    def tracks_at(self, stamps: list[int]) -> list[tuple[int, np.ndarray, np.ndarray]] | None:
        """The front-end's buffered (t_cam_ns, ids, uv) at each stamp, or None if one left the buffer."""
        return self.buffer.tracks_at(stamps)

    def note_request(self, frames: list[Frame]) -> None:
        """Count a feed-forward request on `frames` (the next window waits one spacing after it)."""
        self.report.ff_requests += 1
        self._last_request_ns = int(frames[-1].t_ns)

    def on_feedforward(self, result: Any, extension: bool = False) -> None:
        """Apply a finished feed-forward attempt (extension: a re-solve over a longer span): an InitResult
        starts a candidate; a rejection is counted, and keeps (or ends) the longer re-solves. A time offset
        the window found (runtime.ffinit.time_offset_check) counts towards its adoption."""
        # a filter publishing already was propagated at its offset: a finding is then only counted
        adopted = self._offsets.record(result, self.adopt_time_offset is not None and self.publisher is None)
        if adopted is not None:
            self._adopt_offset(adopted)
        if not isinstance(result, InitResult):
            reason = getattr(result, "reason", type(result).__name__)
            counts = self.report.ff_extension_rejections if extension else self.report.ff_rejections
            counts[reason] = counts.get(reason, 0) + 1
            if not extension:
                self.report.ff_rejection_first.setdefault(reason, str(getattr(result, "detail", "")))
            seed = getattr(result, "seed", None)
            if self.publisher is not None:   # another filter publishes already: nothing to re-solve
                self._resolves.drop()
            elif seed is not None:
                self._resolves.keep(seed, from_model_window=not extension)
            elif extension:
                self._resolves.drop()
            return
        self._resolves.drop()
        if extension:   # the window's own refusal is in ff_rejections: count the re-solve apart
            self.report.ff_extension_accepted += 1
        else:
            self.report.ff_accepted += 1
        if self.publisher is not None or self._tried >= self.cfg.max_candidates:
            return
        start = None
        margin = 50_000_000
        offset_ns = self.offset_ns if "time_offset_s" not in result.info else \
            int(round(float(result.info["time_offset_s"]) * 1e9))      # the offset the state was solved at
        for e in self.buffer.entries:
            if (e.kind == "imu" and e.t_ns >= result.t_ns - margin) or \
               (e.kind == "tracks" and e.t_ns + offset_ns > result.t_ns):
                start = e.seq
                break
        first_imu = next((e for e in self.buffer.entries if e.kind == "imu"), None)
        if start is None or first_imu is None or first_imu.t_ns > result.t_ns - margin:
            self.report.candidates_refused_buffer += 1
            return
        filt = self.make_filter(self.cfg.native)
        filt.initialize_from_state(result.t_ns, result.R_OI, result.p_OI, result.v_OI, result.bg,
                                   result.ba, result.cov, source="feedforward",
                                   time_offset_s=result.info.get("time_offset_s"))
        self._cid += 1
        self._tried += 1
        self.candidates.append(Candidate(self._cid, filt, result, self._newest_ns, start))
        self.report.candidates_started += 1

    def _adopt_offset(self, adopted: float) -> None:
        """Take up the camera-IMU time offset `adopted` (s): later windows' IMU, the native filter and the
        caller; candidates still replaying at another offset are dropped (not counted against
        max_candidates)."""
        self.offset_ns = int(round(adopted * 1e9))
        self.report.time_offset_adopted_s = adopted
        self.report.time_offset_adopted_t_ns = self._newest_ns
        if hasattr(self.native, "set_time_offset"):
            self.native.set_time_offset(adopted)
        for c in list(self.candidates):
            offset = getattr(c.filter, "time_offset_s", None)
            if offset is not None and abs(offset - adopted) > self.cfg.time_offset_agree_s:
                c.status = "offset_dropped"
                self.candidates.remove(c)
                self._tried -= 1
                self.report.candidates_offset_dropped += 1
        self.adopt_time_offset(adopted)

    # ------------------------------------------------------------------ internals
    def _advance_candidates(self) -> list[Published]:
        out: list[Published] = []
        for c in list(self.candidates):
            states = c.step(self.buffer, self.cfg.replay_batch)
            if not c.filter.initialized:
                c.status = "diverged"
                self.report.candidates_diverged += 1
                self.candidates.remove(c)
                continue
            newest = self._newest_cam_ns
            for s in states:
                # within catch_up_s of the newest frame when produced, whether replayed or live (Sec. IV-C)
                live = newest is not None and (newest - int(s.t_cam_ns)) <= self.cfg.catch_up_s * 1e9
                c.consecutive = c.consecutive + 1 if live else 0
            if c.consecutive >= self.cfg.consecutive_states:
                rest = c.step(self.buffer, None)  # what is still buffered: no measurement is dropped
                c.status = "selected"
                self.report.candidates_selected += 1
                self._select(c.filter, "feedforward", c.cid)
                return out + self._publish(states[-1:] + rest)
            if (self._newest_ns - c.created_ns) > self.cfg.abandon_after_s * 1e9:
                c.status = "abandoned"
                self.report.candidates_abandoned += 1
                self.candidates.remove(c)
        return out

    def _publish_native(self, states: list) -> list[Published]:
        if self.publisher is None and states and self.native.initialized:
            src = getattr(self.native, "init_source", None) or "native"
            self._select(self.native, f"native:{src}", 0)
            return self._publish(states)
        return []

    def _select(self, filt: Any, source: str, fid: int) -> None:
        self.publisher = filt
        self.publisher_source = source
        self.publisher_id = fid
        self.report.published_by = source
        if self.report.first_published_by is None:
            self.report.first_published_by = source
        for c in self.candidates:
            if c.filter is not filt and c.status == "replaying":
                c.status = "outrun"
                self.report.candidates_outrun += 1
        self.candidates.clear()
        self.buffer.entries.clear()
        self._frames.clear()
        self._resolves.drop()

    def _publish(self, states: list) -> list[Published]:
        out = []
        for s in states:
            if self.report.first_publish_t_ns is None:
                self.report.first_publish_t_ns = int(s.t_ns)
                self.report.refused_before_first = _refusals(self.native)
            cov = getattr(s, "covariance", None)
            out.append(Published(int(s.t_ns), int(s.t_cam_ns), s.R_OI, s.p_OI, s.v_OI,
                                 self.publisher_source, self.publisher_id,
                                 self.report.restarts_after_divergence,
                                 None if cov is None else np.array(cov[:6, :6])))
        if self.publisher is not None and not self.publisher.initialized:
            self._restart()
        return out

    def _restart(self) -> None:
        """The publishing filter diverged and reset: back to start-up with both initializers armed."""
        self.report.restarts_after_divergence += 1
        self.native = self.publisher
        self.publisher = None
        self._tried = 0
        self.report.published_by = None


def _refusals(native: Any) -> dict:
    """{initializer: {"rejections": {code: n}, "last_reason": str}} of a filter's native initializers, from
    its report (`MsckfEstimator.report()["initializers"]`; a filter without one: {})."""
    report = getattr(native, "report", None)
    inits = (report() if callable(report) else {}).get("initializers") or {}
    return {name: {"rejections": dict(r["rejections"]), "last_reason": r.get("last_reason", "")}
            for name, r in inits.items() if r.get("rejections")}
