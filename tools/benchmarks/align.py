"""`davio bench align`: localising one map session in another, against the ground truth.

Per sequence (a euroc_imu_gt folder, EuRoC-trajectory mode), two sessions are cut from its trajectory at
different starts, their scene built around the whole trajectory (`SimConfig.scene_span = "trajectory"`):
one place, two start poses, so two map frames. Each is tracked once (native start-up) and mapped by the
complete system with the emulated DA3 at every --depth-scales factor (its dense depth-error sigmas
multiplied: the sensitivity rows). The second session is aligned to the first (`runtime.graph.relocalize`)
from the centre views its submaps keep, as `davio map align` does from the archives.

Truth: each session's final trajectory is fitted to its ground truth (SE(3)), giving T_W<-A and T_W<-B;
the true transform is T_AB = T_WA^-1 T_WB. Reported: the yaw and translation error of the estimate
against it (which includes the two fits' own errors, about each session's final ATE), and the RMS error
of B's final trajectory put into A's frame by the estimate and into the world by A's fit, with no fit of
its own (against B's own fitted ATE). Two negative controls must not localise: the second session of
each sequence against the first session of the next (another place and scene style), at every factor;
and against a first session over the same trajectory in another scene of the same style (seed + 1:
the same texture generator, another layout), at x1.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count

NAME = "align"
HELP = "localising a map session in another of the same place, against the ground truth"
DESCRIPTION = __doc__
DEFAULT_SEQUENCES = ("V1_02_medium:room:0:40:38:45", "MH_03_medium:hall:0:60:55:60")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", action="append", default=None,
                   metavar="DIR:STYLE:START_A:SECONDS_A:START_B:SECONDS_B",
                   help="a euroc_imu_gt folder (or its name under ../shared/data/euroc_imu_gt), the scene "
                        "style and the two sessions' spans in seconds (default: "
                        f"{', '.join(DEFAULT_SEQUENCES)})")
    p.add_argument("--depth-scales", default="1,2,5,20",
                   help="comma-separated factors on the emulated DA3's dense depth-error sigmas")
    p.add_argument("--da3", default="base", help="emulated DA3 preset")
    p.add_argument("--seed", type=count(0), default=0, help="seed of the scenes, noise and emulated DA3")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def _parse(spec: str) -> tuple[Path, str, float, float, float, float]:
    parts = spec.split(":")
    if len(parts) != 6:
        raise SystemExit(f"davio bench align: --sequence {spec!r}: expected DIR:STYLE:START_A:SECONDS_A:"
                         "START_B:SECONDS_B")
    folder = Path(parts[0])
    if not folder.is_dir():
        from tools.benchmarks.mapping import SHARED

        folder = SHARED / parts[0]
    if not folder.is_dir():
        raise SystemExit(f"davio bench align: no euroc_imu_gt folder {parts[0]!r} (needs ../shared/data)")
    try:
        spans = [float(x) for x in parts[2:]]
    except ValueError:
        raise SystemExit(f"davio bench align: --sequence {spec!r}: the spans must be numbers") from None
    return folder, parts[1], *spans


def _session(folder: Path, style: str, start: float, seconds: float, seed: int) -> Any:
    from drivers.sim import SimConfig, SimRecording

    cfg = SimConfig(seconds=seconds, start_s=start, seed=seed, style=style, scene_span="trajectory")
    return SimRecording.from_euroc_imu_gt(folder, cfg)


def _tracked(rec: Any, da3: str, seed: int) -> dict:
    """Track a session once; the context `trajectory.run_ablation` replays mappers with."""
    from models.matcher import Matcher
    from runtime.config import DavioConfig
    from tools.benchmarks.mapping_inputs import CachedTruth, SharedMatcher
    from tools.benchmarks.trajectory_inputs import record_tracking

    cfg = DavioConfig()
    run = record_tracking(rec, cfg)
    segs = np.array([p.segment for p in run.published])
    segment = int(segs[-1]) if len(segs) else 0
    return {"run": run, "ctx": {"config": cfg, "camera": rec.rig.camera, "truth": CachedTruth(rec.gt_source),
                                "gt": rec.groundtruth(), "idx": np.nonzero(segs == segment)[0],
                                "segment": segment, "da3": da3, "seed": seed,
                                "matcher": SharedMatcher(Matcher.default(top_k=1024))}}


def _mapped(t: dict, scale: float) -> tuple[list, Any, dict]:
    """(place views, final trajectory, row) of one session mapped with depth errors x scale."""
    from runtime.graph.relocalize import PlaceView
    from tools.benchmarks.trajectory import Ablation, run_ablation
    from tools.benchmarks.trajectory_replay import trajectory

    row, rep = run_ablation(Ablation("davio", "DAVIO", depth_error_scale=scale), t["run"], t["ctx"])
    seg = t["ctx"]["segment"]
    views = [PlaceView(s.index, np.asarray(s.T_MS, np.float64), *s.view) for s in rep.submaps
             if s.segment == seg and s.view is not None]
    final = trajectory(t["run"].published, rep.final, t["ctx"]["idx"])
    return views, final, row


def _fit(final: Any, gt: Any) -> tuple[np.ndarray, float]:
    """(T_WM, ATE m): the SE(3) fit of a final trajectory to its ground truth."""
    from tools.evaluation import ate

    r = ate(final, gt, align_method="se3")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = r.alignment.R, r.alignment.t
    return T, float(r.trans["rmse"])


def _match(fa: Any, fb: Any) -> tuple[np.ndarray, np.ndarray]:
    from models.matcher.matcher import match_stored

    m = match_stored(fa, fb)
    return m.idx_a, m.idx_b


def score(views_a: list, views_b: list, final_a: Any, final_b: Any, gt_a: Any, gt_b: Any) -> dict:
    """Align B to A and compare with the transform the ground truth gives (module docstring)."""
    from runtime.graph.place_consensus import yaw_deg
    from runtime.graph.relocalize import align_sessions
    from tools.evaluation.associate import associate

    t0 = time.perf_counter()
    res = align_sessions(views_a, views_b, _match)
    row: dict = {"localized": res.localized, "reason": res.reason, "align_s": time.perf_counter() - t0,
                 "views": [len(views_a), len(views_b)], "attempts": res.attempts,
                 "verified": len(res.hypotheses), "agreeing": len(res.agreeing), "fit": res.fit,
                 "rejected": dict(res.rejected)}
    T_WA, ate_a = _fit(final_a, gt_a)
    T_WB, ate_b = _fit(final_b, gt_b)
    row["ate_a_m"], row["ate_b_m"] = ate_a, ate_b
    if not res.localized:
        return row
    T_true = np.linalg.inv(T_WA) @ T_WB
    T = res.T_PN
    row["yaw_error_deg"] = (yaw_deg(T[:3, :3]) - yaw_deg(T_true[:3, :3]) + 180.0) % 360.0 - 180.0
    row["translation_error_m"] = float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))
    est, ref = associate(final_b, gt_b)
    T_W = T_WA @ T
    p_W = est.p @ T_W[:3, :3].T + T_W[:3, 3]
    row["b_in_a_rms_m"] = float(np.sqrt(np.mean(np.sum((p_W - ref.p) ** 2, axis=1))))
    return row


def run(args: argparse.Namespace) -> int:
    specs = [_parse(s) for s in (args.sequence or DEFAULT_SEQUENCES)]
    try:
        scales = [float(x) for x in args.depth_scales.split(",") if x.strip()]
    except ValueError:
        raise SystemExit(f"davio bench align: --depth-scales {args.depth_scales!r}: numbers, comma-separated"
                         ) from None
    if not scales or any(not np.isfinite(k) or k <= 0 for k in scales):
        raise SystemExit("davio bench align: --depth-scales must be positive numbers")
    log = (lambda msg: None) if args.json else (lambda msg: print(msg, flush=True))
    t_start = time.perf_counter()
    sessions = []
    for folder, style, sa, da, sb, db in specs:
        pair = []
        for start, seconds, seed in ((sa, da, args.seed), (sb, db, args.seed), (sa, da, args.seed + 1)):
            rec = _session(folder, style, start, seconds, seed)
            log(f"{folder.name} [{start:g} s, +{seconds:g} s], seed {seed}: tracking ...")
            pair.append({"rec": rec, **_tracked(rec, args.da3, seed)})
        sessions.append((folder.name, pair))
    rows = []
    for k in scales:
        mapped = []
        for name, pair in sessions:
            m = [_mapped(t, k) for t in (pair if k == scales[0] else pair[:2])]
            mapped.append((name, pair, m))
            r = score(m[0][0], m[1][0], m[0][1], m[1][1], pair[0]["ctx"]["gt"], pair[1]["ctx"]["gt"])
            rows.append({"sequence": name, "depth_scale": k, "control": False, **r})
            log(_line(rows[-1]))
            if len(m) > 2:
                r = score(m[2][0], m[1][0], m[2][1], m[1][1], pair[2]["ctx"]["gt"], pair[1]["ctx"]["gt"])
                rows.append({"sequence": f"{name} B against A in another scene (seed + 1)", "depth_scale": k,
                             "control": True, **_control(r)})
                log(_line(rows[-1]))
        for i, (name, pair, m) in enumerate(mapped):
            if len(mapped) < 2:
                break
            oname, opair, om = mapped[(i + 1) % len(mapped)]
            r = score(om[0][0], m[1][0], om[0][1], m[1][1], opair[0]["ctx"]["gt"], pair[1]["ctx"]["gt"])
            rows.append({"sequence": f"{name} B against {oname} A", "depth_scale": k, "control": True,
                         **_control(r)})
            log(_line(rows[-1]))
    out = {"sequences": [f"{f.name}:{s}:{a:g}:{b:g}:{c:g}:{d:g}" for f, s, a, b, c, d in specs],
           "seed": args.seed, "da3": args.da3, "rows": rows, "wall_s": time.perf_counter() - t_start}
    if args.out:
        Path(args.out).write_text(strict_dumps(out, indent=1))
    if args.json:
        print(strict_dumps(out, indent=1))
    else:
        _table(rows)
    controls_ok = all(not r["localized"] for r in rows if r["control"])
    return 0 if controls_ok else 1


def _control(r: dict) -> dict:
    keys = ("localized", "reason", "attempts", "verified", "agreeing", "views")
    return {key: v for key, v in r.items() if key in keys}


def _line(r: dict) -> str:
    if r["control"]:
        return (f"  control {r['sequence']}, depth x{r['depth_scale']:g}: "
                f"{'LOCALISED (wrong)' if r['localized'] else 'not localised'} ({r['reason']})")
    if not r["localized"]:
        return f"  {r['sequence']}, depth x{r['depth_scale']:g}: not localised ({r['reason']})"
    return (f"  {r['sequence']}, depth x{r['depth_scale']:g}: yaw error {r['yaw_error_deg']:+.2f} deg, "
            f"translation error {r['translation_error_m']:.3f} m, B in A's frame {r['b_in_a_rms_m']:.3f} m "
            f"(B's own ATE {r['ate_b_m']:.3f} m), {r['agreeing']}/{r['verified']} pairs agree")


def _table(rows: list[dict]) -> None:
    print("| sequence | depth errors | localised | yaw error (deg) | translation error (m) | B in A's frame, "
          "no fit (m) | B's own ATE (m) | A's own ATE (m) | pairs agreeing / verified / tried |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        loc = "yes" if r["localized"] else "no"
        if r["control"] or not r["localized"]:
            print(f"| {r['sequence']} | x{r['depth_scale']:g} | {loc} ({r['reason']}) | - | - | - | "
                  f"{r.get('ate_b_m', float('nan')):.3f} | {r.get('ate_a_m', float('nan')):.3f} | "
                  f"{r['agreeing']} / {r['verified']} / {r['attempts']} |")
            continue
        print(f"| {r['sequence']} | x{r['depth_scale']:g} | {loc} | {r['yaw_error_deg']:+.2f} | "
              f"{r['translation_error_m']:.3f} | {r['b_in_a_rms_m']:.3f} | {r['ate_b_m']:.3f} | "
              f"{r['ate_a_m']:.3f} | {r['agreeing']} / {r['verified']} / {r['attempts']} |")

