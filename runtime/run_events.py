"""The run's events: the moments a robot's supervisor, or the operator of a live module, must hear of while
a run goes, as they happen, each once:

- "publishing": a filter began publishing metric poses (the run's first, or the first after a reset);
- "reset": the publishing filter diverged and was reset: no poses until an initializer publishes again;
- "rig_finding": something is wrong with the rig given (runtime.rig_findings: a gyroscope in deg/s, a wrong
  camera-IMU rotation or time offset), said once per kind;
- "calibration_estimated": the calibration bring-up estimated the camera-IMU rotation and tracking began;
- "prior_localised": a segment of the run was localised in the prior map (poses then carry T_PI), also by
  the mapping of the windows still queued when the data ended (then only the final trajectory is in it);
- "features_lost" / "features_back": fewer than FEW_FEATURES features tracked for FEATURES_LOST_S (a covered,
  dark or blurred camera, a blank wall), and features again;
- "falling_behind": live, tracking fell behind the camera and images were dropped (at most once every
  DROPS_EVERY_S data seconds, with the count since the last such event, and once more when the data ends
  for those not said yet);
- "imu_gap": the IMU stream had a gap (more than `msckf.max_imu_gap_s` between samples, or samples the
  driver lost): a running filter propagates across it on what it has, or is reset when the gap is longer
  than `msckf.max_imu_outage_s` (paced as falling_behind);
- "stamps_back": an IMU stamp came more than STAMPS_BACK_S behind the newest one (a device clock reset, a
  driver that restarted its stamps): the data is dropped until its stamps pass the newest (said once each
  time); the time the stamps take to pass it (B s after a jump back of B s) is an IMU gap, and an outage
  when longer than `msckf.max_imu_outage_s` (runtime.imu.stamps_back);
- "model_error": jobs of the model worker failed (the depth model's start-up and mapping calls: a graph
  that breaks the contract at run time, non-finite outputs, a failing device; a start-up re-solve): a failed
  start-up window is given up while the native initializer goes on, a failed mapping window is not mapped
  (paced as falling_behind, with the first failure's message on one line).

`RunEvents` watches a `runtime.pipeline.VioPipeline` from the pipeline's own thread (the pipeline calls it)
and hands each event to `on_event` (`runtime.session.Session(on_event=...)`; `davio run|live` write them to
`events.jsonl` in the run folder and say them on the console). Under the scheduler, the events of a step
(one IMU sample or frame) reach `on_event` after the poses that step published (the scheduler `flush`es
them), so a reset comes after the last pose of the segment it ends. The counters behind each event stay in
the run report; an event is the moment one of them changed, with its data time.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from runtime.imu.stamps_back import StampsBehind
from runtime.rig_findings import rig_findings, rig_state

KINDS = ("publishing", "reset", "rig_finding", "calibration_estimated", "prior_localised", "features_lost",
         "features_back", "falling_behind", "imu_gap", "stamps_back", "model_error")
STAMPS_BACK_S = 0.1
"""An IMU stamp this far (s) behind the newest one is a clock that went back ("stamps_back"), not a late or
repeated sample."""
MAX_KEPT = 1000
"""Events `RunEvents.log` keeps (a run has a handful; one that resets again and again is bounded)."""
FEW_FEATURES = 10
"""Tracked features below which a frame counts as seeing nothing to track (the filter needs several)."""
FEATURES_LOST_S = 1.0
"""How long (camera seconds) frames must see fewer than FEW_FEATURES before "features_lost" is said: a
single dark or blurred frame is not news."""
DROPS_EVERY_S = 10.0
"""At most one "falling_behind" or "imu_gap" event in this many data seconds (a slow machine drops images all
along; a flaky IMU link loses samples again and again)."""


@dataclass(frozen=True)
class RunEvent:
    """One event.

    Attributes:
        t_ns: sensor-clock time (ns) of the measurement the event was found at.
        t_s: seconds of data since the run's first measurement.
        kind: one of KINDS.
        message: one line for a console.
        detail: the specifics, JSON-ready (per kind: see the module docstring and `RunEvents`).
    """

    t_ns: int
    t_s: float
    kind: str
    message: str
    detail: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """A flat dict: t_ns, t_s, kind, message and the detail's keys (one line of events.jsonl)."""
        return {"t_ns": self.t_ns, "t_s": round(self.t_s, 3), "kind": self.kind, "message": self.message,
                **self.detail}


class RunEvents:
    """The events of one pipeline (see the module docstring).

    Details: "publishing": source (e.g. "feedforward", "native:static"), segment (filter restarts before
    it); "reset": segment (the one that ended), reason (the filter's), resets (so far); "rig_finding": key,
    evidence (runtime.rig_findings.RigFinding); "calibration_estimated": windows_used, R_IC (3x3 rows);
    "prior_localised": segment, source (the prior map), after_end (only when found by the mapping after the
    data ended: then only the final trajectory is in its frame); "features_lost": since_t_ns (the first
    frame with too few), features (on this frame); "features_back": lost_s (how long), features;
    "falling_behind": dropped (since the last such event), total; "imu_gap": gaps (since the last such
    event), longest_s, lost (samples the driver lost in them), total (gaps so far); "stamps_back": back_s
    (how far behind the newest stamp), newest_t_ns.

    Args:
        pipeline: the VioPipeline watched (read: startup, rig_check, bringup, prior).
        on_event: called with each RunEvent on the pipeline's thread, or None (the log only). An exception
            it raises goes up into the run, as one from a Session's on_pose does.
        rig_offset_s: the rig file's camera-IMU time offset (s; None: none given), for the time-offset
            finding's line.
        max_imu_gap_s: a longer time between IMU samples is an imu_gap (`msckf.max_imu_gap_s`, as the
            filter counts gaps).
        max_imu_outage_s: a longer one resets a running filter (`msckf.max_imu_outage_s`): the imu_gap
            event says so instead of "propagates across it".
        look_every_s: how often (data seconds) the rig findings are looked for.
    """

    def __init__(self, pipeline: Any, on_event: Callable[[RunEvent], None] | None = None,
                 rig_offset_s: float | None = None, max_imu_gap_s: float = 0.05,
                 look_every_s: float = 1.0, max_imu_outage_s: float = 0.5) -> None:
        self.pipeline, self.on_event, self.rig_offset_s = pipeline, on_event, rig_offset_s
        self.look_every_s = float(look_every_s)
        self.start_ns: int | None = None
        """The run's first measurement (set by the pipeline)."""
        self.log: list[RunEvent] = []
        """The first MAX_KEPT events."""
        self.counts: dict[str, int] = {}
        self._publishing: tuple[int, str] | None = None
        self._resets = 0
        self._finding_kinds: set[str] = set()
        self._localised: set[int] = set()
        self._latest_ns = 0                       # the latest frame or data-end time seen
        self._next_look_ns: int | None = None
        self._few_since_ns: int | None = None     # the first of the current run of frames with few features
        self._lost = False
        self._dropped_said = 0
        self._next_drop_ns: int | None = None
        self._gaps = [0, 0.0, 0, 0]      # since the last imu_gap event: gaps, longest (s), lost; all gaps
        self._imu_gap_ns = int(max_imu_gap_s * 1e9)
        self._outage_s = float(max_imu_outage_s)
        self._last_imu_ns: int | None = None   # the last IMU sample that reached the filter
        self._back = False                      # "stamps_back" said, the stamps not past the newest yet
        self._behind = StampsBehind(self._imu_gap_ns)   # samples stamped behind the newest one
        self._next_gap_ns: int | None = None
        self._model = [0, 0, ""]                # model job failures: said, seen, the first one's message
        self._next_model_ns: int | None = None
        self.hold = False
        """While True (the scheduler sets it), events wait in `pending` for `flush()`."""
        self.pending: list[RunEvent] = []
        self.look_errors = 0
        """Looks for rig findings that failed (a reporting aid: counted, never raised into the run)..."""
        self.look_error_first: str | None = None
        """...and the first one's message."""

    # -- what the pipeline calls --------------------------------------------------------------
    def on_published(self, out: list) -> None:
        """After states were published (each with .t_ns, .segment, .source): a new publisher is an event."""
        for p in out:
            if (p.segment, p.source) != self._publishing:
                # the resets before this segment (its number counts them) are said before it; one after it,
                # in the same call (its first poses diverged), after it
                self._check_reset(int(p.t_ns), upto=int(p.segment))
                self._publishing = (p.segment, p.source)
                again = "" if self.counts.get("publishing", 0) == 0 else "again "
                self._emit(int(p.t_ns), "publishing", f"publishing metric poses {again}({p.source})"
                           + (f", segment {p.segment}" if p.segment else ""),
                           source=str(p.source), segment=int(p.segment))
        if out:
            self._check_reset(int(out[-1].t_ns))

    def after_imu(self, t_ns: int) -> None:
        """After each IMU sample: a reset found there is said at once, not at the next frame."""
        startup = self.pipeline.startup
        if startup is not None and startup.report.restarts_after_divergence != self._resets:
            self._check_reset(t_ns)

    def after_frame(self, t_ns: int, features: int | None = None) -> None:
        """After each frame (with its number of tracked features): resets, prior-map localisations and the
        features seen at once, rig findings every look_every_s."""
        self._latest_ns = max(self._latest_ns, int(t_ns))
        self._check_reset(t_ns)
        if features is not None:
            self._features(t_ns, int(features))
        if self._gaps[0]:        # gaps gathered: said once their ten seconds are over, not at the next gap
            self._say_gaps(t_ns)
        if self._model[1] > self._model[0]:
            self._say_model(t_ns)
        self._prior_localisations(t_ns)
        if self._next_look_ns is None or t_ns >= self._next_look_ns:
            self._next_look_ns = t_ns + int(self.look_every_s * 1e9)
            try:
                found = rig_findings(rig_state(self.pipeline), self.rig_offset_s)
            except Exception as exc:   # noqa: BLE001 - the run report still holds every counter
                self.look_errors += 1
                self.look_error_first = self.look_error_first or f"{type(exc).__name__}: {exc}"
                found = []
            for finding in found:
                if finding.kind not in self._finding_kinds:
                    self._finding_kinds.add(finding.kind)
                    self._emit(t_ns, "rig_finding", finding.line, key=finding.key, evidence=finding.evidence)

    def after_mapping(self, t_ns: int) -> None:
        """After the windows still queued at the data's end were mapped (`VioPipeline.finish_mapping`):
        localisations in the prior map found there are said now, at the data's last time (t_ns or a later
        one seen), and handed on at once."""
        self._prior_localisations(max(int(t_ns), self._latest_ns), after_end=True)
        self._say_model(max(int(t_ns), self._latest_ns), final=True)
        self.flush()

    def frames_dropped(self, total: int, t_ns: int, final: bool = False) -> None:
        """The live queue has dropped `total` images so far (the scheduler says so after each frame once
        any was dropped, and with `final` when the data ends: drops not said yet are said then)."""
        if total <= self._dropped_said:
            return
        if not final and self._next_drop_ns is not None and t_ns < self._next_drop_ns:
            return
        n, first = total - self._dropped_said, self._dropped_said == 0
        self._dropped_said = total
        self._next_drop_ns = t_ns + int(DROPS_EVERY_S * 1e9)
        since = "" if first else " since the last such event"
        self._emit(t_ns, "falling_behind", (
            f"tracking falls behind the camera: {n} images dropped{since}, {total} in all (the oldest "
            "waiting image goes; IMU samples are all kept)"), dropped=int(n), total=int(total))

    def imu_sample(self, sample: Any) -> None:
        """An IMU sample the pipeline passes on to the filter: a gap before it is an imu_gap, measured as the
        filter does (runtime.msckf.estimator.feed_imu): between finite samples, each later than the last."""
        t = int(sample.t_ns)
        if not (np.isfinite(sample.gyro).all() and np.isfinite(sample.accel).all()):
            return
        prev, lost = self._last_imu_ns, int(getattr(sample, "lost_before", 0) or 0)
        if prev is not None and t <= prev:
            self._behind.behind(t)
            back_s = (prev - t) / 1e9
            if back_s > STAMPS_BACK_S and not self._back:
                self._back = True      # said once until the stamps pass the newest one again
                self._emit(prev, "stamps_back", (
                    f"IMU stamps went back {back_s:.2f} s (a clock reset, or stamps in other units?): every "
                    "sample and image is dropped until the stamps pass the newest one, and the time that "
                    "takes is an IMU gap (a running filter is reset when it is longer than "
                    "msckf.max_imu_outage_s)"),
                    back_s=round(back_s, 6), newest_t_ns=prev)
            return
        # a clock that went back B s passes the newest stamp B s later: B s more without usable samples
        gap_ns = t - prev + self._behind.passed() if prev is not None else 0
        self._back = False
        self._last_imu_ns = t
        if prev is not None and (lost or gap_ns > self._imu_gap_ns):
            self.imu_gap(t, gap_ns / 1e9, lost)

    def imu_gap(self, t_ns: int, gap_s: float, lost: int) -> None:
        """The IMU sample at t_ns follows a gap of gap_s seconds, `lost` samples of it lost by the driver."""
        g = self._gaps
        g[0], g[1], g[2], g[3] = g[0] + 1, max(g[1], float(gap_s)), g[2] + int(lost), g[3] + 1
        self._say_gaps(t_ns)

    def data_ended(self, t_ns: int, frames_dropped: int = 0) -> None:
        """The data ended at t_ns: images dropped and IMU gaps not said yet (held back by the rate bound)
        are said now, and a prior-map localisation taken up after the last frame."""
        self._latest_ns = max(self._latest_ns, int(t_ns))
        self.frames_dropped(frames_dropped, t_ns, final=True)
        self._say_gaps(t_ns, final=True)
        self._say_model(t_ns, final=True)
        self._prior_localisations(t_ns)

    def model_failures(self, t_ns: int, total: int, first: str) -> None:
        """`total` start-up or mapping model jobs have failed so far, the first with message `first`."""
        if total > self._model[1]:
            text = " ".join(str(first).split())             # one line, however the exception was worded
            text = text if len(text) <= 300 else text[:297] + "..."
            self._model[1], self._model[2] = int(total), self._model[2] or text
            self._say_model(t_ns)

    def _say_model(self, t_ns: int, final: bool = False) -> None:
        said, total, first = self._model
        if total <= said or (not final and self._next_model_ns is not None and t_ns < self._next_model_ns):
            return
        self._next_model_ns = t_ns + int(DROPS_EVERY_S * 1e9)
        self._model[0] = total
        since = "" if said == 0 else " since the last such event"
        self._emit(t_ns, "model_error", (
            f"model worker jobs failed: {total - said}{since}, {total} in all (first: {first}); a failed "
            "start-up window or re-solve is given up (the native initializer goes on), a failed mapping "
            "window is not mapped"),
            failed=int(total - said), total=int(total), first=first)

    def _say_gaps(self, t_ns: int, final: bool = False) -> None:
        n, longest, lost, total = self._gaps
        if n == 0 or (not final and self._next_gap_ns is not None and t_ns < self._next_gap_ns):
            return
        self._next_gap_ns = t_ns + int(DROPS_EVERY_S * 1e9)
        self._gaps = [0, 0.0, 0, total]
        what = f"a {longest:.3f} s gap" if n == 1 else f"{n} gaps since the last such event, the longest " \
            f"{longest:.3f} s"
        lost_text = f" ({lost} samples lost by the driver)" if lost else ""
        fate = ("a running filter is reset (longer than msckf.max_imu_outage_s)" if longest > self._outage_s
                else "a running filter propagates across it")
        self._emit(t_ns, "imu_gap", f"IMU stream: {what}{lost_text}; {fate}",
                   gaps=int(n), longest_s=round(longest, 4), lost=int(lost), total=int(total))

    def calibration_estimated(self, t_ns: int, report: Any) -> None:
        """The bring-up finished (its runtime.bringup.BringUpReport): tracking starts on the estimate."""
        rep = asdict(report)
        self._emit(t_ns, "calibration_estimated", (
            f"calibration bring-up done: the camera-IMU rotation estimated from {rep['windows_used']} "
            f"windows (fit {rep['fit_rms_deg'] or 0.0:.2f} deg rms); tracking starts, the lever arm and time "
            "offset estimated online"), windows_used=int(rep["windows_used"]), R_IC=rep["R_IC"])

    def flush(self) -> None:
        """Hand the events held back (`hold`) to on_event, in order."""
        while self.pending:
            event = self.pending.pop(0)
            if self.on_event is not None:
                self.on_event(event)

    def report(self) -> dict:
        """Counts by kind, how many events the log did not keep, failed looks for rig findings."""
        rep = {"counts": dict(self.counts), "not_kept": max(0, sum(self.counts.values()) - len(self.log))}
        if self.look_errors:
            rep["look_errors"], rep["look_error_first"] = self.look_errors, self.look_error_first
        return rep

    # -- inside ------------------------------------------------------------------------------
    def _features(self, t_ns: int, features: int) -> None:
        if features >= FEW_FEATURES:
            if self._lost:
                lost_s = (t_ns - self._few_since_ns) / 1e9
                self._emit(t_ns, "features_back", f"features tracked again ({features}) after {lost_s:.1f} s",
                           lost_s=round(lost_s, 3), features=features)
            self._few_since_ns, self._lost = None, False
            return
        if self._few_since_ns is None:
            self._few_since_ns = t_ns
        if not self._lost and t_ns - self._few_since_ns >= int(FEATURES_LOST_S * 1e9):
            self._lost = True
            lost_s = (t_ns - self._few_since_ns) / 1e9
            self._emit(t_ns, "features_lost", (
                f"fewer than {FEW_FEATURES} features tracked for {lost_s:.1f} s: the camera sees nothing to "
                "track (covered, dark, blurred, a blank wall?); a running filter has only the IMU"),
                since_t_ns=int(self._few_since_ns), features=features)

    def _check_reset(self, t_ns: int, upto: int | None = None) -> None:
        """Say the resets not said yet: all of them, or (`upto`) those before segment `upto` began."""
        startup = self.pipeline.startup
        if startup is None:
            return
        now = startup.report.restarts_after_divergence
        count = now if upto is None else min(now, upto)
        if count <= self._resets:
            return
        self._resets = count
        segment = count - 1      # segment k publishes after k resets, and the (k+1)-th ends it
        # the filter keeps the reason of its own latest reset: the one said when no later one happened
        reason = (getattr(startup.native, "last_reset_reason", None) if count == now else None) or "unknown"
        if self._publishing is not None and self._publishing[0] <= segment:
            self._publishing = None
        self._emit(t_ns, "reset", f"the filter publishing poses diverged ({reason}) and was reset: no poses "
                   "until an initializer publishes again", segment=int(segment), reason=str(reason),
                   resets=int(count))

    def _prior_localisations(self, t_ns: int, after_end: bool = False) -> None:
        """Segments newly localised: those whose transform the tracking thread took up (poses published in
        the prior frame from then on), and after the end those the localizer found without one taken up
        (the final trajectory's prior-frame poses use the localizer's newest transform)."""
        prior = self.pipeline.prior
        if prior is None:
            return
        found = set(prior.localized_at_ns)
        if after_end:
            loc = prior.localizer
            found |= {seg for seg in loc.segments() if loc.T_PN(seg) is not None}
        for seg in sorted(found - self._localised):
            self._localised.add(seg)
            late = after_end and seg not in prior.localized_at_ns
            where = (": the final trajectory is also in its frame (found by the mapping after the data ended)"
                     if late else ": poses now also in its frame")
            detail = {"after_end": True} if late else {}
            self._emit(t_ns, "prior_localised", f"localised in the prior map {prior.source}"
                       + (f" (segment {seg})" if seg else "") + where,
                       segment=int(seg), source=str(prior.source), **detail)

    def _emit(self, t_ns: int, kind: str, message: str, **detail: Any) -> None:
        start = self.start_ns if self.start_ns is not None else t_ns
        event = RunEvent(int(t_ns), max(0.0, (int(t_ns) - start) / 1e9), kind, message, detail)
        self.counts[kind] = self.counts.get(kind, 0) + 1
        if len(self.log) < MAX_KEPT:
            self.log.append(event)
        if self.hold:
            self.pending.append(event)
        elif self.on_event is not None:
            self.on_event(event)
