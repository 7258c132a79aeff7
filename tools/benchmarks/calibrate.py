"""`davio bench calibrate FOLDER...`: `davio calibrate` on simulated recordings with a known rig.

For each `davio simulate` folder (and each factor of --pose-error-scales on the emulated DA3's unconditioned
pose errors, models.emulated_da3.params.POSE_ERROR_FIELDS), the extrinsics and time offset are withheld,
estimated by the hand-eye bring-up and the filter's online calibration, written as a Kalibr camchain,
read back with calib.load_rig, and compared with the simulator's rig (sensor.yaml T_IC and the manifest's
time offset): rotation (deg), lever arm (cm), time offset (ms, signed), the filter's 1-sigma, whether
`davio calibrate`'s default refusal rules accept it, and when each error settled below the goal
(< 0.3 deg, < 1 cm, < 1 ms after 60 s of motion). The bring-up's camera rotations come from the EMULATED
DA3 (not DA3 results) or, with `--sources two-view`, from two-view fits of the tracked features (no model:
what a user without DA3 gets; the pose-error factors do not apply to it, and after the bring-up the
start-up is the native initializer's alone, as in any run without a model).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from tools.cli_types import number, positive

NAME = "calibrate"
HELP = "davio calibrate on simulated recordings with a known rig: errors of the written camchain"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "folders",
        type=Path,
        nargs="+",
        help="`davio simulate` folders (e.g. --seconds 60 --time-offset 0.005)",
    )
    p.add_argument("--seconds", type=positive, default=None, help="only the first S seconds of each")
    p.add_argument(
        "--pose-error-scales",
        default="1",
        metavar="K,K,...",
        help="factors on the emulated DA3's unconditioned pose errors (e.g. 1,2,5,20)",
    )
    p.add_argument(
        "--scales-on",
        default="first",
        choices=["first", "all"],
        help="apply the factors other than 1 to the first folder only, or to all",
    )
    p.add_argument("--preset", default="base", help="emulated DA3 preset")
    p.add_argument(
        "--sources",
        default="emulated",
        metavar="S,S",
        help="where the bring-up's camera rotations come from, each a row per folder: emulated (the "
        "emulated DA3), two-view (the tracked features, no model)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON result to this file")


SOURCES = ("emulated", "two-view")


def measure(folder: Path, scale: float, seconds: float | None, preset: str = "base",
            source: str = "emulated") -> dict:
    """One calibration of `folder` with the pose-error factor `scale` (source "emulated") or without a model
    (source "two-view"); errors of the written file."""
    from calib import load_rig
    from models.emulated_da3 import EmulatedDA3
    from models.emulated_da3.params import POSE_ERROR_FIELDS, make_params
    from tools.calibrate.checks import Thresholds, judge
    from tools.calibrate.core import calibrate
    from tools.calibrate.output import errors_against, estimated_rig, paths_for, rotation_deg
    from tools.calibrate.report import build_report, write_outputs
    from tools.run_io import open_recording, read_manifest

    rec = open_recording(folder)
    rig = rec.driver.rig
    cfg = read_manifest(folder / "manifest.json").get("config") or {}
    true_T, true_dt = np.asarray(rig.T_IC), float(cfg.get("time_offset_s") or 0.0)
    base = make_params(preset)
    overrides = {k: getattr(base, k) * scale for k in POSE_ERROR_FIELDS}
    cam = rig.camera
    model = None
    if source == "emulated":
        model = EmulatedDA3(rec.ground_truth_source, cam.K, cam.width, cam.height, preset=preset, **overrides)
    t0 = time.perf_counter()
    run = calibrate(rec.driver.events(), rig, model, seconds=seconds)
    wall = time.perf_counter() - t0
    verdict = judge(run, Thresholds())
    row: dict = {
        "folder": str(folder),
        "preset": cfg.get("preset"),
        "source": source,
        "pose_error_scale": scale if source == "emulated" else None,
        "sensor_s": run.sensor_s,
        "wall_s": wall,
        "verdict": verdict.code,
        "message": verdict.message,
        "bringup": run.bringup,
        "excitation_rms_dps": run.excitation.rms_rate_dps,
        "true_time_offset_ms": 1e3 * true_dt,
    }
    bu = run.bringup or {}
    if bu.get("R_IC") is not None:
        row["bringup_rot_err_deg"] = rotation_deg(np.array(bu["R_IC"]), true_T[:3, :3])
        row["bringup_done_s"] = (bu["done_t_ns"] - run.t0_ns) * 1e-9
    final = run.final
    if final is None:
        return row
    std = final.std()
    if std is not None:
        row.update(std_rot_deg=std[0], std_lever_cm=100 * std[1], std_offset_ms=1e3 * std[2])
    # write the camchain exactly as `davio calibrate` does and read it back
    with tempfile.TemporaryDirectory() as tmp:
        paths = paths_for(Path(tmp) / "camchain.yaml")
        if std is not None:
            report = build_report(
                run,
                verdict,
                Thresholds(),
                source,
                str(folder),
                {"source": "simulator", "T_IC": true_T, "time_offset_s": true_dt},
                paths,
            )
            write_outputs(run, rig, paths, report)
            back = load_rig(paths["camchain"])
            row["settled_s"] = report["reference"]["errors"]["settled_s"]
        else:
            back = estimated_rig(rig, final, "x")
    R, p, dt = back.T_IC[:3, :3], back.T_IC[:3, 3], back.time_offset_s
    row.update(
        rot_err_deg=rotation_deg(R, true_T[:3, :3]),
        lever_err_cm=float(100 * np.linalg.norm(p - true_T[:3, 3])),
        offset_err_ms=float(1e3 * (dt - true_dt)),
    )
    # mean error over the last 10 s (how steady the end is)
    last = [s for s in run.samples if s.t_cam_ns >= final.t_cam_ns - 10_000_000_000]
    errs = np.array(
        [
            [e["rotation_deg"], e["lever_arm_cm"], abs(e["time_offset_ms"])]
            for e in (errors_against(s, true_T, true_dt) for s in last)
        ]
    )
    row.update(
        rot_err_deg_last10s=float(errs[:, 0].mean()),
        lever_err_cm_last10s=float(errs[:, 1].mean()),
        offset_err_ms_last10s=float(errs[:, 2].mean()),
    )
    return row


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError
    from runtime.json_out import strict_dumps

    try:
        scales = [number(s) for s in args.pose_error_scales.split(",") if s.strip()]
    except argparse.ArgumentTypeError:
        raise ConfigError("--pose-error-scales must be finite numbers separated by commas, "
                          f"got {args.pose_error_scales!r}") from None
    if not scales or any(not (s >= 0) for s in scales):
        raise ConfigError("--pose-error-scales must hold numbers >= 0")
    sources = [s.strip() for s in args.sources.split(",") if s.strip()]
    if not sources or any(s not in SOURCES for s in sources):
        raise ConfigError(f"--sources must hold {' or '.join(SOURCES)} separated by commas, "
                          f"got {args.sources!r}")
    rows = []
    for i, folder in enumerate(args.folders):
        for source in sources:
            for k in scales if source == "emulated" else [1.0]:
                if k != 1.0 and args.scales_on == "first" and i > 0:
                    continue
                rows.append(measure(folder, k, args.seconds, args.preset, source))
                if not args.json:
                    _print_row(rows[-1], header=len(rows) == 1)
    res = {
        "goal": {"rot_deg": 0.3, "lever_cm": 1.0, "offset_ms": 1.0, "after_s": 60},
        "model": f"EMULATED DA3 ({args.preset}) -- not a real network" if "emulated" in sources else None,
        "sources": sources,
        "rows": rows,
    }
    if args.out is not None:
        args.out.write_text(strict_dumps(res, indent=1))
    if args.json:
        print(strict_dumps(res))
    return 0


_COLS = (
    ("preset", "preset", "{}"),
    ("source", "rotations", "{}"),
    ("pose_error_scale", "DA3 err x", "{:g}"),
    ("sensor_s", "s", "{:.0f}"),
    ("bringup_done_s", "bring-up s", "{:.1f}"),
    ("bringup_rot_err_deg", "bring-up deg", "{:.2f}"),
    ("rot_err_deg", "rot deg", "{:.3f}"),
    ("lever_err_cm", "lever cm", "{:.2f}"),
    ("offset_err_ms", "dt ms", "{:+.3f}"),
    ("std_rot_deg", "1s rot", "{:.3f}"),
    ("std_lever_cm", "1s cm", "{:.2f}"),
    ("std_offset_ms", "1s ms", "{:.3f}"),
    ("verdict", "verdict", "{}"),
    ("wall_s", "wall s", "{:.0f}"),
)


def _print_row(row: dict, header: bool) -> None:
    if header:
        print(
            "davio calibrate on simulated recordings (rotations: EMULATED DA3 or two-view fits of the "
            "tracks; goal < 0.3 deg / 1 cm / 1 ms after 60 s)"
        )
        print(" ".join(f"{h:>12}" for _, h, _ in _COLS))
    cells = []
    for key, _, fmt in _COLS:
        v = row.get(key)
        cells.append(f"{'-' if v is None else fmt.format(v):>12}")
    print(" ".join(cells), flush=True)
