"""What a run found wrong with the rig it was given, one finding per kind: a gyroscope's scale (deg/s
logged as rad/s) or a camera-IMU rotation that disagree with the camera, as the start-up's DA3 windows, the
tracked features (runtime.rig_check) or the calibration bring-up judged them, and a camera-IMU time offset
the start-up found. Each finding has a stable key for programs (events of kind "rig_finding",
runtime.run_events) and one line for a console (the end-of-run summary, tools.run_summary, and the lines
said during a run)."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

EXTRINSICS_WARNING_WINDOWS = 2
"""Windows refused as extrinsics_rotation before the console blames the rig's rotation: one window is one
hand-eye fit of four rotations (`davio bench rig-checks` saw no such window with the right rotation, and
several per recording with it inverted wherever the rig turns about two axes: BENCHMARKS.md "Start-up
checks of the rig")."""


@dataclass(frozen=True)
class RigFinding:
    """One finding.

    Attributes:
        key: what is wrong: "gyro_scale", "extrinsics_rotation", "extrinsics_suspect" (a suspicion: a
            camera-IMU rotation degrees off, below the finding's bounds), "time_offset", or "rig_check_error"
            (the check from the tracked features ended early).
        evidence: what found it: "feedforward" (the start-up's DA3 windows), "tracks" (two-view fits of the
            tracked features), or "bringup" (the calibration bring-up's windows).
        line: the console's line, starting with its kind ("GYROSCOPE SCALE (tracked features): ...").
    """

    key: str
    evidence: str
    line: str

    @property
    def kind(self) -> str:
        """The line up to its first colon, e.g. "GYROSCOPE SCALE (tracked features)": one per key and
        evidence."""
        return self.line.split(":", 1)[0]


def time_offset_line(startup: dict, rig_offset_s: float | None) -> str | None:
    """The console's word on a camera-IMU time offset the start-up found far from the rig's: adopted,
    solved at, or only found (runtime.ffinit.time_offset_check); None when it found none."""
    found = startup.get("time_offset_findings") or 0
    if not found:
        return None
    rig_ms = (rig_offset_s or 0.0) * 1e3
    adopted = startup.get("time_offset_adopted_s")
    first = startup.get("time_offset_first") or startup.get("ff_time_offset_first") or \
        (startup.get("ff_rejection_first") or {}).get("time_offset", "") or "-"
    rig = f"(the rig says {rig_ms:+.1f} ms)"
    if adopted is not None:
        what = f"adopted {adopted * 1e3:+.1f} ms {rig}"
    elif startup.get("ff_time_offset_s") is not None:
        what = f"a window was solved at {startup['ff_time_offset_s'] * 1e3:+.1f} ms {rig}"
    else:
        what = "not adopted"
    windows = "1 window fits" if found == 1 else f"{found} windows fit"
    return (f"CAMERA-IMU TIME OFFSET: {windows} another offset, {what}; the first: {first}. Put "
            "the offset in the rig file (Kalibr timeshift_cam_imu: t_imu = t_cam + shift)")


def rig_findings(pipeline_report: dict, rig_offset_s: float | None) -> list[RigFinding]:
    """The rig findings so far, from a pipeline report (or the part of one holding `startup`, `rig_check`
    and `bringup`, as `rig_state` gives it). `rig_offset_s`: the rig file's camera-IMU time
    offset (s; None: none given)."""
    out = []
    startup = pipeline_report.get("startup") or {}
    refused = startup.get("ff_rejections") or {}
    first = startup.get("ff_rejection_first") or {}
    if refused.get("gyro_scale"):
        out.append(RigFinding("gyro_scale", "feedforward", (
            f"GYROSCOPE SCALE: {refused['gyro_scale']} windows refused, the first: "
            f"{first.get('gyro_scale', '')}. Fix the IMU's units or scale; every filter integrates them "
            "too")))
    if refused.get("extrinsics_rotation", 0) >= EXTRINSICS_WARNING_WINDOWS:
        out.append(RigFinding("extrinsics_rotation", "feedforward", (
            f"CAMERA-IMU ROTATION: {refused['extrinsics_rotation']} windows refused, the first: "
            f"{first.get('extrinsics_rotation', '')}. Check the rig file's T_cam_imu / T_imu_cam, or run "
            "with --withhold-extrinsics to estimate it")))
    check = pipeline_report.get("rig_check") or {}     # without a model: from the tracked features
    if check.get("gyro_scale"):
        out.append(RigFinding("gyro_scale", "tracks", (
            f"GYROSCOPE SCALE (tracked features): {check['gyro_scale']}. Fix the IMU's units or scale; the "
            "filter integrates them")))
    if check.get("error"):
        out.append(RigFinding("rig_check_error", "tracks",
                              f"rig check from the tracked features ended early: {check['error']}"))
    if check.get("extrinsics_rotation"):
        out.append(RigFinding("extrinsics_rotation", "tracks", (
            f"CAMERA-IMU ROTATION (tracked features): {check['extrinsics_rotation']}. Check the rig file's "
            "T_cam_imu / T_imu_cam, or run with --withhold-extrinsics to estimate it")))
    if check.get("extrinsics_suspect"):
        out.append(RigFinding("extrinsics_suspect", "tracks", (
            f"CAMERA-IMU ROTATION? (tracked features): {check['extrinsics_suspect']}. A rotation off by "
            "degrees resets the filter and skews its scale: recalibrate, or let the filter estimate it "
            "([msckf] calib_extrinsics = true in a --config file)")))
    line = time_offset_line(startup, rig_offset_s)
    if line:
        out.append(RigFinding("time_offset", "feedforward", line))
    bu = pipeline_report.get("bringup")
    if bu:
        from runtime.bringup import gyro_blamed

        gyro = gyro_blamed(bu)
        if gyro:
            out.append(RigFinding("gyro_scale", "bringup", (
                f"GYROSCOPE SCALE (bring-up): {bu['rejections']['gyro_scale']} windows refused, the first: "
                f"{gyro}. Fix the IMU's units or scale")))
    return out


def rig_state(pipeline: Any) -> dict:
    """The parts of a runtime.pipeline.VioPipeline's `report()` the findings are read from, cheaply: the
    start-up's, the tracked-feature check's and a bring-up's not done yet."""
    state: dict = {}
    if pipeline.startup is not None:
        rep = pipeline.startup.report
        state["startup"] = {k: getattr(rep, k) for k in (
            "ff_rejections", "ff_rejection_first", "time_offset_findings", "time_offset_adopted_s",
            "time_offset_first", "ff_time_offset_first", "ff_time_offset_s")}
    if pipeline.rig_check is not None:
        rep = pipeline.rig_check.report
        state["rig_check"] = {k: getattr(rep, k) for k in ("gyro_scale", "extrinsics_rotation",
                                                             "extrinsics_suspect", "error")}
    if pipeline.bringup is not None and not pipeline.bringup.done:
        state["bringup"] = asdict(pipeline.bringup.report)
    return state


def rig_lines(pipeline_report: dict, rig_offset_s: float | None) -> list[str]:
    """The findings' console lines (`rig_findings`): at the end of a run (tools.run_summary.recovery_lines)
    and, as they are found, during one (runtime.run_events)."""
    return [f.line for f in rig_findings(pipeline_report, rig_offset_s)]
