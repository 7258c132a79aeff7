"""When `davio calibrate` refuses to write a rig file, and why.

In this order (the first that applies is the refusal; each names what was observed):

1. the replay failed or was interrupted (a live run ends with Ctrl-C: its data is judged);
2. too little data to judge the motion: the bring-up did not complete within less than a second of data
   (RMS rates over so short a span say nothing);
3. the rotation excitation is insufficient: fewer than two principal axes of the gyro stream with an RMS
   rate of at least `min_axis_rate_dps` (a hand–eye calibration needs rotation about two non-parallel
   axes; a static or purely translating recording has none);
4. too little data: the bring-up did not complete and the recording is shorter than `min_seconds` (the
   bring-up needed 6.3-9.3 s on the benchmark recordings);
5. the hand–eye bring-up never completed (too few windows rotating >= 5 deg, or every estimate was
   rejected: the rejections are named);
6. the filter never published a calibrated state (no covariance of the calibration);
7. the final 1-sigma (worst direction of each block of the filter's covariance) exceeds
   `max_rot_std_deg`, `max_lever_std_m` or `max_offset_std_ms`;
8. the lever arm is still moving: over the last `settle_window_s` of the final segment it came farther than
   `max_lever_drift_m` from its final value (the filter's 1-sigma does not show it), or the final segment
   (after the bring-up, or after a filter reset) is shorter than `settle_window_s`, so that it cannot tell.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from tools.calibrate.core import CalibrationRun

SAMPLE_SLACK_S = 0.2
"""The calibrated states are collected every 0.1 s of camera time: a final segment this much shorter than
the settling window still covers it."""

MIN_RATE_SECONDS = 1.0
"""Below a second of gyro data the principal-axis RMS rates do not describe the motion: a run that short is
refused as too little data before its rotation is judged."""


@dataclass(frozen=True)
class Thresholds:
    """Refusal thresholds (the `davio calibrate` options of the same names)."""

    min_axis_rate_dps: float = 2.0
    """RMS angular rate (deg/s) the second-strongest principal rotation axis must reach. Measured
    (BENCHMARKS.md "Calibration-withheld bring-up to a rig file"): static and purely translating recordings
    stay below 1 deg/s (EuRoC gyro noise: about 0.14 deg/s per axis at 200 Hz); the 'slow' hand-held
    preset reaches 6.5 / 3.9 / 3.5 deg/s and still met the goals after 60 s."""
    min_seconds: float = 6.0
    """Below this many seconds of data, a run whose bring-up did not complete is refused as too short
    rather than as badly excited: the bring-up completed after 6.3 s (aggressive), 8.3 s (euroc) and 9.3 s
    (slow) on the benchmark recordings (BENCHMARKS.md "Calibration-withheld bring-up to a rig file")."""
    max_rot_std_deg: float = 0.1
    max_lever_std_m: float = 0.005
    max_offset_std_ms: float = 0.3
    """The 1-sigma limits are a third to a half of the goals (0.3 deg, 1 cm, 1 ms): on simulated recordings
    the filter's final 1-sigma was 1-6x smaller than its actual error (lever arm worst)."""
    max_lever_drift_m: float = 0.004
    settle_window_s: float = 15.0
    """The lever arm must have stayed within 0.4 cm of its final value over the last 15 s. Measured
    (BENCHMARKS.md "A lever arm still moving"): the 60 s recordings turning at 34-47 deg/s RMS moved 0.06-0.24
    cm over their last 15 s and ended 0.23-0.48 cm off; the 'slow' ones (3.5-6.5 deg/s) moved 0.49-0.59 cm
    and one ended 1.39 cm off with a 1-sigma of 0.29 cm; 'slow' over 120 s moved 0.20-0.22 cm and ended
    0.59-0.83 cm off. The lever arm is seen only through rotation, so a slow rig needs a longer recording."""


@dataclass
class Verdict:
    ok: bool
    code: str
    """"ok" or the refusal: "replay_failed", "too_little_data", "insufficient_rotation", "bringup_incomplete",
    "no_calibrated_state", "uncertain", "unsettled"."""
    message: str


def _fmt_rates(rates: list) -> str:
    return ", ".join(f"{r:.1f}" for r in rates)


def settling(run: CalibrationRun, window_s: float) -> dict | None:
    """How far each estimate came from its final value over the last `window_s` of camera time in the final
    segment: {"window_s" (the states' span within it), "segment_s" (the final segment's span),
    "lever_arm_m", "rotation_deg", "time_offset_ms", "samples"}; None without samples."""
    final = run.final
    if final is None:
        return None
    start = final.t_cam_ns - int(round(window_s * 1e9))
    segment = [s for s in run.samples if s.segment == final.segment]
    last = [s for s in segment if s.t_cam_ns >= start]
    lever = max(float(np.linalg.norm(s.p_IC - final.p_IC)) for s in last)
    from tools.calibrate.output import rotation_deg

    rot = max(rotation_deg(s.R_IC, final.R_IC) for s in last)
    offset = max(abs(s.time_offset_s - final.time_offset_s) for s in last)
    return {"window_s": (final.t_cam_ns - last[0].t_cam_ns) * 1e-9,
            "segment_s": (final.t_cam_ns - segment[0].t_cam_ns) * 1e-9, "lever_arm_m": lever,
            "rotation_deg": rot, "time_offset_ms": 1e3 * offset, "samples": len(last)}


def _images_end_early(ex) -> str:
    """' (the images cover ... of the IMU's ...)' when the IMU runs on well past the images, else ''."""
    imu_s = float(getattr(ex, "imu_seconds", 0.0) or 0.0)
    if imu_s > ex.seconds + 1.0 and imu_s > 1.2 * ex.seconds:
        return (f" (the images cover {ex.seconds:.1f} s of the IMU's {imu_s:.1f} s: the rotation is "
                f"measured where there are images; is the camera's data cut short?)")
    return ""


def judge(run: CalibrationRun, th: Thresholds) -> Verdict:
    """The first refusal rule that applies (see the module docstring), else ok."""
    if run.status != "complete" and not (run.live and run.status == "interrupted"):
        return Verdict(False, "replay_failed", f"the replay did not complete ({run.status}: {run.reason})")
    ex = run.excitation
    rates = list(ex.rms_rate_dps) or [0.0, 0.0, 0.0]
    axes_ok = sum(r >= th.min_axis_rate_dps for r in rates)
    bu = run.bringup or {}
    short = not bu.get("R_IC") and not ex.seconds >= th.min_seconds
    early = _images_end_early(ex)
    too_little = Verdict(
        False,
        "too_little_data",
        f"too little data: {ex.seconds:.1f} s with images{early}, and the bring-up needs several seconds of "
        f"rotation (it completed after 6-9 s on the benchmark recordings; refused below "
        f"{th.min_seconds:g} s) - record at least a minute, rotating the rig about at least two axes",
    )
    if short and not ex.seconds >= MIN_RATE_SECONDS:
        return too_little
    if axes_ok < 2:
        return Verdict(
            False,
            "insufficient_rotation",
            f"the motion does not excite the rotation enough: {axes_ok} of 3 principal axes reach "
            f"{th.min_axis_rate_dps:g} deg/s RMS (observed {_fmt_rates(rates)} deg/s over "
            f"{ex.seconds:.1f} s with images{early}; need 2) - rotate the rig about at least two "
            f"different axes; "
            f"bring-up: {_bringup_text(bu)}",
        )
    if short:
        return too_little
    if not bu.get("R_IC"):
        from runtime.bringup import gyro_blamed

        gyro = gyro_blamed(bu)
        return Verdict(
            False,
            "bringup_incomplete",
            f"the hand-eye bring-up never completed: {_bringup_text(bu)} (principal-axis RMS rates "
            f"{_fmt_rates(rates)} deg/s) - "
            + (f"GYROSCOPE SCALE: {gyro}; fix the IMU's units or scale" if gyro
               else "record longer, or with more rotation per second"),
        )
    final = run.final
    std = None if final is None else final.std()
    if std is None:
        return Verdict(
            False,
            "no_calibrated_state",
            "the filter never published a state with calibration after the bring-up "
            f"(published by: {(run.pipeline.get('startup') or {}).get('published_by')})",
        )
    rot, lev, dt = std
    over = []
    if not rot <= th.max_rot_std_deg:
        over.append(f"rotation {rot:.3f} deg > {th.max_rot_std_deg:g}")
    if not lev <= th.max_lever_std_m:
        over.append(f"lever arm {100 * lev:.2f} cm > {100 * th.max_lever_std_m:g}")
    if not 1e3 * dt <= th.max_offset_std_ms:
        over.append(f"time offset {1e3 * dt:.3f} ms > {th.max_offset_std_ms:g}")
    if over:
        return Verdict(
            False,
            "uncertain",
            "the calibration is too uncertain after "
            f"{run.sensor_s:.1f} s (1-sigma {'; '.join(over)}) - record longer or with more motion, "
            "or relax --max-rot-std-deg / --max-lever-std-m / --max-offset-std-ms",
        )
    moved = settling(run, th.settle_window_s)
    if moved is not None and moved["segment_s"] < th.settle_window_s - SAMPLE_SLACK_S:
        return Verdict(
            False,
            "unsettled",
            f"the filter's final segment covers only {moved['segment_s']:.1f} s of calibrated states (the "
            f"lever arm's settling is judged over the last {th.settle_window_s:g} s; "
            f"{'a filter reset' if final.segment else 'the bring-up'} came before) - record longer, or "
            "relax --settle-window-s",
        )
    if moved is not None and not moved["lever_arm_m"] <= th.max_lever_drift_m:
        return Verdict(
            False,
            "unsettled",
            f"the lever arm is still moving after {run.sensor_s:.1f} s: it came "
            f"{100 * moved['lever_arm_m']:.2f} cm from its final value over the last "
            f"{moved['window_s']:.1f} s (allowed "
            f"{100 * th.max_lever_drift_m:g} cm; its 1-sigma says {100 * lev:.2f} cm) - record longer, or "
            "with more rotation (the lever arm is seen only through rotation), or relax --max-lever-drift-m",
        )
    return Verdict(
        True,
        "ok",
        f"1-sigma rotation {rot:.3f} deg, lever arm {100 * lev:.2f} cm, time offset {1e3 * dt:.3f} ms",
    )


def _bringup_text(bu: dict) -> str:
    if not bu:
        return "not run"
    rej = ", ".join(f"{k} x{v}" for k, v in sorted((bu.get("rejections") or {}).items())) or "none"
    state = "done" if bu.get("R_IC") else "not done"
    return (
        f"{state}, {bu.get('windows_used', 0)} windows used, {bu.get('windows_skipped_static', 0)} skipped "
        f"(rotating < {bu.get('min_rotation_deg', 5.0):g} deg), {bu.get('attempts', 0)} estimates, "
        f"rejections: {rej}"
    )
