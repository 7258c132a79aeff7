"""Run DAVIO with the camera–IMU extrinsics and time offset withheld and collect the calibration.

The pipeline (runtime.pipeline.VioPipeline) first runs the hand–eye bring-up (R_IC and the gyro bias
from DA3 vs preintegrated rotations), then starts tracking with zero lever arm and time offset and the
filter's online calibration of all three on. After every published pose (at most every
`sample_every_s` of camera time) we read the publishing filter's state (`startup.publisher.state()`:
R_IC, p_IC, time_offset_s and the (7, 7) calib_covariance [dphi right on R_IC, dp_IC, dt]).

Beside that, the gyro stream gives the rotation excitation: the principal axes of sum(w w^T dt) and,
per axis, the RMS rate and the rotation angle swept about it. A hand–eye calibration needs rotation
about at least two non-parallel axes.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from runtime.config import DavioConfig
from runtime.event_window import first_seconds
from runtime.events import ImuSample


@dataclass
class CalibSample:
    """The publishing filter's calibration at one frame."""

    t_cam_ns: int
    R_IC: np.ndarray
    p_IC: np.ndarray
    time_offset_s: float
    calib_covariance: np.ndarray | None
    segment: int

    def std(self) -> tuple[float, float, float] | None:
        """1-sigma (rotation deg, lever arm m, time offset s): the square root of the largest eigenvalue of
        each block (the worst direction), or None without a covariance."""
        return covariance_std(self.calib_covariance)


def covariance_std(cov: np.ndarray | None) -> tuple[float, float, float] | None:
    """(rot deg, lever m, offset s) 1-sigma of a (7, 7) [dphi, dp, dt] covariance, worst direction."""
    if cov is None or np.shape(cov) != (7, 7):
        return None
    c = np.asarray(cov, float)
    rot = float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(c[:3, :3]).max(), 0.0))))
    lev = float(np.sqrt(max(np.linalg.eigvalsh(c[3:6, 3:6]).max(), 0.0)))
    dt = float(np.sqrt(max(c[6, 6], 0.0)))
    return rot, lev, dt


@dataclass
class Excitation:
    """Rotation excitation of the gyro stream (IMU frame) while there are images: principal axes of
    sum(w w^T dt)."""

    seconds: float = 0.0
    """Seconds of gyro data measured (between the first and the last image)."""
    imu_seconds: float = 0.0
    """Seconds of gyro data in the whole recording (more than `seconds` when the images end early)."""
    axes: list = field(default_factory=list)
    """(3, 3) rows: the principal axes, strongest first."""
    rms_rate_dps: list = field(default_factory=list)
    """RMS angular rate about each principal axis, deg/s."""
    angle_deg: list = field(default_factory=list)
    """Rotation swept about each principal axis, sum |w . axis| dt, deg."""


class ExcitationMeter:
    """Collects the gyro samples and the image stamps; at the end, the second moment and the swept angle
    per principal axis of the gyro samples between the first and the last image (the bring-up and the
    filter see the rotation only where there are images: an IMU file that runs on after them does not
    excite the calibration). Without images, every sample."""

    def __init__(self) -> None:
        self._t: int | None = None
        self._ts: list[int] = []
        self._w: list[np.ndarray] = []
        self._dt: list[float] = []
        self._frames: list[int] = []     # first and last image stamp

    def add(self, t_ns: int, gyro: np.ndarray) -> None:
        w = np.asarray(gyro, float)
        if not np.all(np.isfinite(w)):
            return
        if self._t is not None:
            dt = (int(t_ns) - self._t) * 1e-9
            if 0.0 < dt < 0.1:  # gaps carry no rate
                self._ts.append(int(t_ns))
                self._w.append(w)
                self._dt.append(dt)
        self._t = int(t_ns)

    def frame(self, t_ns: int) -> None:
        """An image at `t_ns`."""
        if not self._frames:
            self._frames = [int(t_ns), int(t_ns)]
        self._frames[1] = max(self._frames[1], int(t_ns))

    def result(self) -> Excitation:
        dt_all = np.array(self._dt)
        imu_s = float(dt_all.sum()) if len(dt_all) else 0.0
        keep = np.ones(len(dt_all), bool)
        if self._frames:
            t = np.array(self._ts, np.int64)
            keep = (t > self._frames[0]) & (t <= self._frames[1])
        w = np.array(self._w).reshape(-1, 3)[keep]
        dt = dt_all[keep]
        T = float(dt.sum()) if len(dt) else 0.0
        if T <= 0.0:
            return Excitation(0.0, imu_s, np.eye(3).tolist(), [0.0] * 3, [0.0] * 3)
        vals, vecs = np.linalg.eigh((w.T * dt) @ w / T)
        order = np.argsort(vals)[::-1]
        axes = vecs[:, order].T
        angles = np.degrees(np.abs(w @ axes.T).T @ dt)
        rms = np.degrees(np.sqrt(np.maximum(vals[order], 0.0)))
        return Excitation(T, imu_s, axes.tolist(), rms.tolist(), angles.tolist())


@dataclass
class CalibrationRun:
    """What `calibrate` collected.

    Attributes:
        samples: the publishing filter's calibration over time (CalibSample, camera time order).
        bringup: the hand–eye bring-up report (runtime.bringup.BringUpReport as a dict), None when the
            rig had extrinsics.
        excitation: the gyro stream's rotation excitation.
        pipeline: the pipeline's report() at the end.
        status, reason: how the replay ended ("complete", "interrupted", "failed").
        t0_ns: the first event's time (plots and the report count seconds from it).
        sensor_s: seconds of data replayed.
        live: the events came from a live device (Ctrl-C is how such a run ends: "interrupted" is normal).
    """

    samples: list[CalibSample]
    bringup: dict | None
    excitation: Excitation
    pipeline: dict
    status: str
    reason: str | None
    t0_ns: int
    sensor_s: float
    live: bool = False

    @property
    def final(self) -> CalibSample | None:
        return self.samples[-1] if self.samples else None


def calibration_config(config: DavioConfig | None = None) -> DavioConfig:
    """`config` without mapping (calibration needs only the filter; the map would cost model calls)."""
    cfg = config or DavioConfig()
    return replace(cfg, mapping=replace(cfg.mapping, enabled=False))


def calibrate(
    events: Iterable[Any],
    rig: Any,
    model: Any,
    config: DavioConfig | None = None,
    seconds: float | None = None,
    model_latency_s: float = 0.5,
    sample_every_s: float = 0.1,
    progress: Callable[[float, str], None] | None = None,
    alert: Callable[[str], None] | None = None,
    live: bool = False,
    on_event: Callable[[Any], None] | None = None,
    before_data: Callable[[], Any] | None = None,
) -> CalibrationRun:
    """Replay `events` through DAVIO with `rig`'s extrinsics and time offset withheld; collect the filter's
    calibration states and the rotation excitation.

    Args:
        events: a recording's time-ordered ImuSample / Frame events (a driver's `events()`).
        rig: calib.Rig with the camera intrinsics (T_IC and time_offset_s are ignored: withheld).
        model: a DepthModel (DA3 ONNX or emulated), or None: the bring-up then takes the camera's rotations
            from two-view fits of the tracked features.
        seconds: only the first S seconds of data (`runtime.event_window.first_seconds`).
        sample_every_s: camera seconds between collected calibration states.
        progress: called with (sensor seconds, phase) about every 5 s of data.
        alert: called with each run event's line (runtime.run_events, tools.event_output.EventConsole) as
            the run finds it: the bring-up's estimate, a rig finding such as a gyroscope in deg/s refused by
            the bring-up, a filter reset.
        live: `events` come from a live driver (runtime.session.Session.run_live: real time, bounded
            queues, model results applied when ready); Ctrl-C ends the data, not the calibration.
        on_event: called with each runtime.run_events.RunEvent as it happens (e.g. a
            tools.event_output.EventFile), after `alert`.
        before_data: called once the session is built, before the first event is read: a live driver's
            `start` (a started camera drops the images the run has not read yet).
    """
    from runtime.session import Session

    withheld = rig.replace(T_IC=None, time_offset_s=None)
    from tools.event_output import EventConsole, chain_events

    console = None if alert is None else EventConsole(alert)
    session = Session(withheld, model, calibration_config(config), on_event=chain_events(console, on_event),
                      max_unread_poses=1)      # poses() is never read here
    pipe = session.pipeline
    samples: list[CalibSample] = []
    step_ns = int(sample_every_s * 1e9)

    def take(force: bool = False) -> None:
        st = pipe.startup
        filt = None if st is None else (st.publisher or (st.native if st.native.initialized else None))
        s = None if filt is None else filt.state()
        if s is None:
            return
        if not force and samples and int(s.t_cam_ns) - samples[-1].t_cam_ns < step_ns:
            return
        if samples and int(s.t_cam_ns) <= samples[-1].t_cam_ns:
            return
        cov = None if s.calib_covariance is None else np.array(s.calib_covariance)
        samples.append(
            CalibSample(
                int(s.t_cam_ns),
                np.array(s.R_IC),
                np.array(s.p_IC),
                float(s.time_offset_s),
                cov,
                int(st.report.restarts_after_divergence),
            )
        )

    session.on_pose = lambda _pose: take()
    meter = ExcitationMeter()
    first: list[int] = []

    def feed() -> Iterator[Any]:
        last_report = -1
        for ev in events if seconds is None else first_seconds(events, seconds):
            t = int(ev.t_ns)
            if not first:
                first.append(t)
            rel = (t - first[0]) * 1e-9
            if isinstance(ev, ImuSample):
                meter.add(t, ev.gyro)
            else:
                meter.frame(t)
            if progress is not None and int(rel) // 5 != last_report:
                last_report = int(rel) // 5
                progress(
                    rel,
                    "bring-up" if pipe.startup is None else (pipe.startup.report.published_by or "starting"),
                )
            yield ev

    if before_data is not None:
        before_data()
    if live:
        res = session.run_live(feed(), keep_partial=True)
    else:
        res = session.replay(feed(), model_latency_s=model_latency_s, keep_partial=True)
    take(force=True)
    rep = pipe.report()
    return CalibrationRun(
        samples,
        rep.get("bringup"),
        meter.result(),
        rep,
        res.status,
        res.reason,
        first[0] if first else 0,
        float(res.scheduler.sensor_s),
        live,
    )


def stderr_progress(rel_s: float, phase: str) -> None:
    print(f"  t = {rel_s:6.1f} s  ({phase})", file=sys.stderr, flush=True)


def stderr_alert(line: str) -> None:
    print(f"  {line}", file=sys.stderr, flush=True)


def as_dict(x: Any) -> dict:
    return asdict(x)
