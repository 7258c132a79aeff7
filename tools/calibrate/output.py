"""The outputs of `davio calibrate`: the Kalibr camchain (+ IMU YAML), the report and the plots.

The camchain's cam0 holds the given intrinsics, `T_cam_imu` = inverse of the estimated T_IC and
`timeshift_cam_imu` = the estimated offset with Kalibr's convention t_imu = t_cam + shift (DAVIO's
`time_offset_s`, unchanged). The report (strict JSON) holds the bring-up's windows, residuals and
rejections, the excitation, the final estimate with its 1-sigma, the convergence over time and, when the
recording has its own extrinsics (EuRoC sensor.yaml, `davio simulate` folders), the errors against them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tools.calibrate.core import CalibrationRun, CalibSample


def paths_for(out: Path) -> dict[str, Path]:
    """The files written for camchain `out`: the IMU YAML (named so that calib.load_rig finds it beside the
    camchain), the report, the plot and the run's events (one JSON line each, written as they happen)."""
    out = Path(out)
    if "camchain" in out.name:
        imu = out.with_name(out.name.replace("camchain-imucam", "imu").replace("camchain", "imu"))
    else:
        imu = out.with_name("imu.yaml")
    stem = out.with_suffix("") if out.suffix in (".yaml", ".yml") else out
    return {
        "camchain": out,
        "imu": imu,
        "report": Path(f"{stem}.report.json"),
        "plot": Path(f"{stem}.convergence.png"),
        "events": Path(f"{stem}.events.jsonl"),
    }


def estimated_rig(rig: Any, sample: CalibSample, name: str) -> Any:
    T_IC = np.eye(4)
    T_IC[:3, :3] = sample.R_IC
    T_IC[:3, 3] = sample.p_IC
    return rig.replace(T_IC=T_IC, time_offset_s=float(sample.time_offset_s), name=name)


def rotation_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    from runtime.geometry import so3_log

    return float(np.degrees(np.linalg.norm(so3_log(np.asarray(Ra).T @ np.asarray(Rb)))))


def errors_against(sample: CalibSample, T_IC_ref: np.ndarray | None, offset_ref: float | None) -> dict:
    """Rotation (deg), lever arm (cm) and time offset (ms, signed est - ref) against a reference."""
    out: dict = {}
    if T_IC_ref is not None:
        T = np.asarray(T_IC_ref, float)
        out["rotation_deg"] = rotation_deg(sample.R_IC, T[:3, :3])
        out["lever_arm_cm"] = float(100 * np.linalg.norm(sample.p_IC - T[:3, 3]))
    if offset_ref is not None:
        out["time_offset_ms"] = float(1e3 * (sample.time_offset_s - offset_ref))
    return out


def convergence(
    run: CalibrationRun, T_IC_ref: np.ndarray | None = None, offset_ref: float | None = None
) -> dict:
    """Per collected state (seconds from the first event): the change from the final estimate and the
    1-sigma, and the errors against the reference when given."""
    final = run.final
    rows: dict[str, list] = {
        k: []
        for k in (
            "t_s",
            "segment",
            "rot_from_final_deg",
            "p_IC_m",
            "time_offset_ms",
            "rot_std_deg",
            "lever_std_m",
            "offset_std_ms",
        )
    }
    ref_rows: dict[str, list] = {"rotation_deg": [], "lever_arm_cm": [], "time_offset_ms": []}
    for s in run.samples:
        rows["t_s"].append((s.t_cam_ns - run.t0_ns) * 1e-9)
        rows["segment"].append(s.segment)
        rows["rot_from_final_deg"].append(rotation_deg(s.R_IC, final.R_IC))
        rows["p_IC_m"].append(s.p_IC.tolist())
        rows["time_offset_ms"].append(1e3 * s.time_offset_s)
        std = s.std() or (float("nan"),) * 3
        rows["rot_std_deg"].append(std[0])
        rows["lever_std_m"].append(std[1])
        rows["offset_std_ms"].append(1e3 * std[2])
        if T_IC_ref is not None or offset_ref is not None:
            e = errors_against(s, T_IC_ref, offset_ref)
            for k in ref_rows:
                ref_rows[k].append(e.get(k))
    if T_IC_ref is not None or offset_ref is not None:
        rows["error_vs_reference"] = ref_rows
    return rows


def settle_time(t: list, values: list, limit: float) -> float | None:
    """First time from which |value| stays <= limit to the end (None if never)."""
    v = np.abs(np.asarray([np.nan if x is None else x for x in values], float))
    bad = np.flatnonzero(~(v <= limit))
    if not len(v):
        return None
    if not len(bad):
        return float(t[0])
    k = int(bad[-1]) + 1
    return float(t[k]) if k < len(t) else None


def plot_convergence(path: Path, conv: dict, title: str) -> Path:
    """Three panels over time: rotation (change from final, or error vs reference), lever arm components
    (and error), time offset, each with its 1-sigma band."""
    from tools.evaluation.plots import _pyplot

    plt = _pyplot()
    t = np.asarray(conv["t_s"], float)
    fig, axs = plt.subplots(3, 1, figsize=(9, 8.5), sharex=True)
    ref = conv.get("error_vs_reference")
    rot_std = np.asarray(conv["rot_std_deg"], float)
    ax = axs[0]
    ax.plot(t, conv["rot_from_final_deg"], "C0", lw=1, label="angle to the final R_IC")
    if ref and any(v is not None for v in ref["rotation_deg"]):
        ax.plot(t, np.asarray(ref["rotation_deg"], float), "C3", lw=1, label="error vs reference")
    ax.fill_between(t, 0, rot_std, color="C0", alpha=0.2, label="1-sigma (worst axis)")
    ax.set_ylabel("rotation [deg]")
    ax.set_yscale("symlog", linthresh=0.05)
    ax.legend(loc="upper right", fontsize=8)
    ax = axs[1]
    p = np.asarray(conv["p_IC_m"], float).reshape(-1, 3) * 100
    lev = np.asarray(conv["lever_std_m"], float) * 100
    for j, c in enumerate("xyz"):
        ax.plot(t, p[:, j], f"C{j}", lw=1, label=f"p_IC {c}")
        ax.fill_between(t, p[:, j] - lev, p[:, j] + lev, color=f"C{j}", alpha=0.12)
    if ref and any(v is not None for v in ref["lever_arm_cm"]):
        ax.plot(t, np.asarray(ref["lever_arm_cm"], float), "k--", lw=1, label="|error| vs reference")
    ax.set_ylabel("lever arm [cm]")
    ax.legend(loc="upper right", fontsize=8, ncol=2)
    ax = axs[2]
    dt = np.asarray(conv["time_offset_ms"], float)
    ds = np.asarray(conv["offset_std_ms"], float)
    ax.plot(t, dt, "C0", lw=1, label="time offset (t_imu = t_cam + shift)")
    ax.fill_between(t, dt - ds, dt + ds, color="C0", alpha=0.2, label="1-sigma")
    if ref and any(v is not None for v in ref["time_offset_ms"]):
        err = np.asarray(ref["time_offset_ms"], float)
        ax.plot(t, dt - err, "k--", lw=1, label="reference")
    ax.set_ylabel("time offset [ms]")
    ax.set_xlabel("t [s] from the first measurement")
    ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
