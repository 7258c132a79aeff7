"""`davio bench rig-checks-two-view`: the model-free rig checks (runtime/rig_check.py) on every motion preset
and on real EuRoC IMU recordings, with the rig right and with the mistakes they name.

Per recording the KLT tracker runs once over the images; its tracks and the IMU feed four checks side by
side: the right rig, the gyroscope logged in deg/s (every gyro sample x 57.3), the camera-IMU rotation
inverted (T_cam_imu given as T_imu_cam), and the rig's rotation 5 deg off (about the camera's optical axis: a
calibration a few degrees out, the `extrinsics_suspect` tier). Per variant: spans judged (of
`RigCheckConfig.max_pairs`), the median and largest gyro/camera rotation ratio, the hand-eye fit's distance
from the rig's rotation and its RMS against the rig's own, and whether each finding was made. With the right
rig a finding is a false alarm. No depth model is involved.
"""
from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

import numpy as np

from tools.benchmarks.rig_checks import add_recording_arguments
from tools.cli_types import count

NAME = "rig-checks-two-view"
HELP = "the model-free rig checks (gyroscope scale, camera-IMU rotation from the tracks): right vs wrong"
DESCRIPTION = __doc__
VARIANTS = ("right", "deg/s", "inverted", "5deg")
OFF_DEG = 5.0
"""The `5deg` variant's error in the rig's camera-IMU rotation (deg, about the camera's z axis)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_recording_arguments(p, 60.0)
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def measure(rec) -> dict:
    """{variant: the check's report} for one recording (see the module docstring)."""
    from runtime.events import Frame, ImuSample
    from runtime.msckf.tracker import KltTracker
    from runtime.rig_check import TwoViewRigCheck

    rig = rec.rig
    R_IC = np.asarray(rig.T_IC, float)[:3, :3]
    focal = float(np.sqrt(rig.camera.fx * rig.camera.fy))
    offset = float(rig.time_offset_s or 0.0)
    from scipy.spatial.transform import Rotation

    off = R_IC @ Rotation.from_euler("z", OFF_DEG, degrees=True).as_matrix()
    checks = {"right": TwoViewRigCheck(R_IC, offset, focal), "deg/s": TwoViewRigCheck(R_IC, offset, focal),
              "inverted": TwoViewRigCheck(R_IC.T, offset, focal), "5deg": TwoViewRigCheck(off, offset, focal)}
    scale = {"right": 1.0, "deg/s": float(np.degrees(1.0)), "inverted": 1.0, "5deg": 1.0}
    tracker = KltTracker(rig.camera)
    for ev in rec.events():
        if isinstance(ev, ImuSample):
            g = np.asarray(ev.gyro, float)
            for name, c in checks.items():
                c.on_imu(ev.t_ns, g * scale[name])
        elif isinstance(ev, Frame):
            if all(c.done for c in checks.values()):
                break
            res = tracker.track(ev)
            for c in checks.values():
                c.on_tracks(res.t_ns, res.ids, res.xy)
    return {name: asdict(c.report) for name, c in checks.items()}


def summarise(rep: dict, variant: str) -> dict:
    """One row: the figures and whether each finding was made (a false alarm on the right rig)."""
    return {"judged": rep["spans_judged"], "still": rep["spans_still"],
            "untracked": rep["spans_without_tracks"],
            "ratio_median": rep["gyro_ratio_median"], "ratio_max": rep["gyro_ratio_max"],
            "gyro_named": rep["gyro_scale"] is not None, "fit_deg": rep["extrinsics_fit_deg"],
            "fit_rms_deg": rep["extrinsics_fit_rms_deg"], "rig_rms_deg": rep["extrinsics_rig_rms_deg"],
            "rotation_named": rep["extrinsics_rotation"] is not None,
            "inverted_named": "inverted" in (rep["extrinsics_rotation"] or ""),
            "suspect_named": rep.get("extrinsics_suspect") is not None,
            "variant": variant, "error": rep["error"]}


def run(args: argparse.Namespace) -> int:
    from runtime.json_out import strict_dumps
    from tools.benchmarks.rig_checks import _recordings

    result: dict = {"recordings": {}}
    f = (lambda v, d=2: "     -" if v is None else f"{v:6.{d}f}")  # noqa: E731
    if not args.json:
        print("model-free rig checks: gyro / camera rotation angle per 0.5 s span, hand-eye fit of the spans")
        print(f"  {'recording':24s} {'variant':8s} {'judged':>6s} {'still':>5s} {'untr.':>5s} {'ratio':>6s} "
              f"{'max':>6s} {'gyro named':>10s} {'fit deg':>7s} {'fit rms':>7s} {'rig rms':>7s} "
              f"{'rot. named':>10s} {'suspected':>9s}")
    for name, make in _recordings(args):
        reports = measure(make())
        rows = {v: summarise(reports[v], v) for v in VARIANTS}
        result["recordings"][name] = {"rows": rows, "reports": reports}
        if not args.json:
            for v, r in rows.items():
                named = "inverted" if r["inverted_named"] else ("yes" if r["rotation_named"] else "no")
                gyro = "yes" if r["gyro_named"] else "no"
                print(f"  {name:24s} {v:8s} {r['judged']:6d} {r['still']:5d} {r['untracked']:5d} "
                      f"{f(r['ratio_median'])} {f(r['ratio_max'])} {gyro:>10s} "
                      f"{f(r['fit_deg'], 1):>7s} {f(r['fit_rms_deg']):>7s} {f(r['rig_rms_deg']):>7s} "
                      f"{named:>10s} {'yes' if r['suspect_named'] else 'no':>9s}", flush=True)
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=1))
    if args.json:
        print(strict_dumps(result))
    return 0
