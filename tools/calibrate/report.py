"""The `davio calibrate` report (a strict-JSON dict) and the files written when the estimate is accepted."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from tools.calibrate.checks import Thresholds, Verdict, settling
from tools.calibrate.core import CalibrationRun
from tools.calibrate.output import convergence, errors_against, estimated_rig, settle_time


def build_report(
    run: CalibrationRun,
    verdict: Verdict,
    th: Thresholds,
    model_desc: str,
    recording: str,
    reference: dict,
    paths: dict[str, Path],
) -> dict:
    """Everything the evidence needs: status, bring-up, excitation, final estimate + 1-sigma, convergence,
    errors against the reference (when the recording has one)."""
    from tools.run_io import versions

    T_ref = reference.get("T_IC")
    off_ref = reference.get("time_offset_s")
    final = run.final
    rep: dict[str, Any] = {
        "status": "ok" if verdict.ok else "refused",
        "refusal": None if verdict.ok else verdict.code,
        "message": verdict.message,
        "recording": recording,
        "model": model_desc,
        "sensor_s": run.sensor_s,
        "replay": {"status": run.status, "reason": run.reason},
        "thresholds": asdict(th),
        "convention": "T_IC: camera pose in the IMU frame (x_I = T_IC x_C); T_cam_imu = inv(T_IC); "
        "t_imu = t_cam + timeshift_cam_imu (Kalibr, = DAVIO time_offset_s)",
        "bringup": run.bringup,
        "bringup_done_s": None
        if not (run.bringup or {}).get("done_t_ns")
        else (run.bringup["done_t_ns"] - run.t0_ns) * 1e-9,
        "excitation": asdict(run.excitation),
        "estimate": None,
        "reference": None,
        "convergence": None,
        "pipeline": {k: run.pipeline.get(k) for k in ("startup", "filter", "tracking", "events")},
        "files": {"camchain": None, "imu": None, "report": str(paths["report"]), "plot": None,
                  "events": str(paths["events"]) if paths["events"].exists() else None},
        "versions": versions(),
    }
    if final is not None:
        std = final.std()
        T_IC = np.eye(4)
        T_IC[:3, :3], T_IC[:3, 3] = final.R_IC, final.p_IC
        rep["estimate"] = {
            "T_IC": T_IC.tolist(),
            "T_cam_imu": np.linalg.inv(T_IC).tolist(),
            "timeshift_cam_imu_s": final.time_offset_s,
            "std": None
            if std is None
            else {"rotation_deg": std[0], "lever_arm_m": std[1], "time_offset_ms": 1e3 * std[2]},
            "calib_covariance": None if final.calib_covariance is None else final.calib_covariance.tolist(),
            "t_s": (final.t_cam_ns - run.t0_ns) * 1e-9,
            "filter_segments": final.segment + 1,
            "states_collected": len(run.samples),
            # how far each estimate came from its final value over the last settle_window_s (refusal 8)
            "settling": settling(run, th.settle_window_s),
        }
        conv = convergence(run, T_ref, off_ref)
        rep["convergence"] = conv
        if T_ref is not None or off_ref is not None:
            err = errors_against(final, T_ref, off_ref)
            ref = conv["error_vs_reference"]
            t = conv["t_s"]
            err["settled_s"] = {
                "rotation_0.3deg": settle_time(t, ref["rotation_deg"], 0.3) if T_ref is not None else None,
                "lever_arm_1cm": settle_time(t, ref["lever_arm_cm"], 1.0) if T_ref is not None else None,
                "time_offset_1ms": settle_time(t, ref["time_offset_ms"], 1.0)
                if off_ref is not None
                else None,
            }
            rep["reference"] = {
                "source": reference.get("source"),
                "T_IC": None if T_ref is None else np.asarray(T_ref).tolist(),
                "time_offset_s": off_ref,
                "errors": err,
            }
    return rep


def write_outputs(run: CalibrationRun, rig: Any, paths: dict[str, Path], report: dict) -> None:
    """The camchain and the IMU YAML (atomic writes); their paths go into the report."""
    from calib.kalibr import write_kalibr

    est = report["estimate"]
    std = est["std"]
    comment = (
        f"davio calibrate: {report['recording']}\nmodel: {report['model']}\n"
        f"1-sigma: rotation {std['rotation_deg']:.3f} deg, lever arm {100 * std['lever_arm_m']:.2f} cm, "
        f"time offset {std['time_offset_ms']:.3f} ms after {report['sensor_s']:.1f} s; "
        "timeshift_cam_imu: t_imu = t_cam + shift"
    )
    if getattr(rig.camera, "distortion_model", "") == "rational":
        note = ("the camchain keeps the camera's rational distortion model (OpenCV's k1 k2 p1 p2 k3 k4 k5 "
                "k6, a factory calibration's): DAVIO reads it, Kalibr and OpenVINS 2.7 do not; calibrate "
                "the lens with Kalibr for them")
        comment += "\n" + note
        report["camchain_note"] = note
    new = estimated_rig(rig, run.final, name=f"davio_calibrate_{paths['camchain'].stem}")
    write_kalibr(new, paths["camchain"], paths["imu"] if rig.imu is not None else None, comment=comment)
    report["files"]["camchain"] = str(paths["camchain"])
    report["files"]["imu"] = str(paths["imu"]) if rig.imu is not None else None


def summary_lines(report: dict) -> list[str]:
    """The console summary."""
    lines = [f"NOTE: {report['camchain_note']}"] if report.get("camchain_note") else []
    bu = report.get("bringup") or {}
    if bu:
        rej = ", ".join(f"{k} x{v}" for k, v in sorted((bu.get("rejections") or {}).items())) or "none"
        fit, val = bu.get("fit_rms_deg"), bu.get("validation_rms_deg")
        done = report.get("bringup_done_s")
        lines.append(
            f"hand-eye bring-up: {'done' if bu.get('R_IC') else 'NOT done'}; "
            f"{bu.get('windows_used', 0)} windows used, {bu.get('windows_skipped_static', 0)} skipped "
            f"(too little rotation), {bu.get('attempts', 0)} estimates, rejections {rej}"
            + (
                f"; fit RMS {fit:.2f} deg, validation {val:.2f} deg"
                if fit is not None and val is not None
                else ""
            )
            + ("" if done is None else f"; done at {done:.1f} s")
        )
    ex = report["excitation"]
    lines.append(
        "rotation excitation: principal-axis RMS rates "
        + ", ".join(f"{r:.1f}" for r in ex["rms_rate_dps"])
        + " deg/s, swept "
        + ", ".join(f"{a:.0f}" for a in ex["angle_deg"])
        + f" deg over {ex['seconds']:.1f} s with images"
        + (f" (the IMU runs {ex['imu_seconds']:.1f} s)" if ex.get("imu_seconds", 0.0) > ex["seconds"] + 1.0
           else "")
    )
    est = report.get("estimate")
    if est is not None:
        T = np.array(est["T_IC"])
        std = est["std"] or {}
        lines.append(
            f"estimate after {report['sensor_s']:.1f} s: p_IC [{', '.join(f'{v:.4f}' for v in T[:3, 3])}] m, "
            f"timeshift_cam_imu {1e3 * est['timeshift_cam_imu_s']:.3f} ms; 1-sigma rotation "
            f"{std.get('rotation_deg', float('nan')):.3f} deg, lever arm "
            f"{100 * std.get('lever_arm_m', float('nan')):.2f} cm, time offset "
            f"{std.get('time_offset_ms', float('nan')):.3f} ms"
        )
        moved = est.get("settling")
        if moved:
            lines.append(
                f"over the last {moved['window_s']:.0f} s the estimate came within "
                f"{100 * moved['lever_arm_m']:.2f} cm, {moved['rotation_deg']:.3f} deg and "
                f"{moved['time_offset_ms']:.3f} ms of its final value"
            )
    ref = report.get("reference")
    if ref:
        e = ref["errors"]
        parts = []
        if e.get("rotation_deg") is not None:
            parts += [f"rotation {e['rotation_deg']:.3f} deg", f"lever arm {e['lever_arm_cm']:.2f} cm"]
        if e.get("time_offset_ms") is not None:
            parts.append(f"time offset {e['time_offset_ms']:+.3f} ms")
        lines.append(f"against {ref['source']}: " + ", ".join(parts))
    f = report["files"]
    written = [v for v in (f.get("camchain"), f.get("imu"), f.get("report"), f.get("plot"), f.get("events"))
               if v]
    lines.append(f"{'accepted' if report['status'] == 'ok' else 'REFUSED'}: {report['message']}")
    lines.append("outputs: " + ", ".join(written))
    return lines
