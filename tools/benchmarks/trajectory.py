"""`davio bench trajectory`: DAVIO's causal and final trajectories against the odometry (paper Sec. VII,
Q2 and the ablation table), on simulated sequences with the emulated DA3.

For each sequence (images rendered along the real EuRoC V1_02_medium and MH_03_medium trajectories with the
real IMU, whole length by default; motion presets with a synthetic IMU, which revisit their 6 x 5 m box, by
default with the in-flight errors measured on the real EuRoC IMU added, `--preset-imu`):
  1. the recording is tracked once by the live pipeline with the native initializer and the feed-forward
     start-up off (trajectory_inputs.py): the published poses are the odometry row, and the keyframe
     windows, the mapping queue and the sensor time each mapping result would be applied at (FastClock,
     `--model-latency` s) are recorded; tracking does not depend on mapping, so every variant below is
     replayed offline on this one run (trajectory_replay.py), with the poses a live run would publish;
  2. rows odometry (the published poses), causal (each pose with the correction in effect when it was
     published) and final (every pose with the completed per-node corrections) of the complete system:
     ATE (SE(3) alignment, no scale, over the last published segment as `davio run` scores it), coverage
     (fraction of the sequence covered by published poses, at most 0.1 s per pose) and T_f (first
     published state, s after the sequence start); ratios final/odometry and causal/odometry;
  3. ablations on the same windows (the paper's table): without pose conditioning (`Mapper(conditioned=
     False)`), graph poses fixed (`graph=False`), without revisits (`RevisitConfig(enabled=False)`), without
     the drift gate (`RevisitConfig(drift_gate=False)`): F@10 as `davio bench mapping` scores it (visible
     reference, 4 cm voxels, 10 cm; the map is in the map frame M and moved by the variant's final
     trajectory's SE(3) alignment), final and causal ATE, the graph's counters and its lambdas against
     the true log-depth scale (mapping_scale.py); and the emulator's sensitivity rows: the complete system
     with every dense depth-error sigma of the emulated DA3 x2, x5 and x20 (the claims above rest on it);
  4. the odometry's drift per distance travelled next to OpenVINS figures taken from the shared data;
  5. with `--error-scales K,...`: the complete system replayed on the same run with the odometry's error
     multiplied by each K, its structure kept (trajectory_error_scale.py): whether the graph's share of the
     correction depends on how large the odometry's error is.
Goals: final ATE <= 0.7 x odometry on every sequence, causal ATE no worse than the odometry.
Everything is simulated: the depth model is the emulated DA3 (models/emulated_da3), not DA3; the start-up
is the native initializer in every row (the feed-forward start-up would change the tracking run).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.benchmarks.mapping import SHARED, Source, _split_style
from tools.cli_types import count, number, number_in

NAME = "trajectory"
HELP = ("causal and final map-frame trajectories vs the odometry (ATE, coverage, T_f, drift) with the "
        "paper's mapping ablations, on simulated sequences")
DESCRIPTION = __doc__

DEFAULT_PRESETS = ("euroc",)
PRESET_SECONDS = 60.0
PRESET_IMU = "euroc-measured"
"""The presets' synthetic IMU: the datasheet densities plus the in-flight errors measured on the real EuRoC
IMU (ImuErrorModel.euroc_measured). With the datasheet densities alone the odometry is too good for the graph
to matter (the EASY verdict); the EuRoC-trajectory sequences replay the real IMU."""
DEFAULT_SEQUENCES: tuple[tuple[str, str], ...] = (("V1_02_medium", "room"), ("MH_03_medium", "hall"))
"""EuRoC-trajectory defaults: (folder under shared/data/euroc_imu_gt, scene style), whole length."""
OPENVINS_SIM = SHARED.parent / "openvins_sim" / "udel_gore_mono_20hz"
GOAL_FINAL_RATIO = 0.7
GOAL_CAUSAL_RATIO = 1.0
EASY_FRACTION = 0.5
"""A sequence is called easy when the odometry's ATE per path length is below this fraction of OpenVINS's on
real EuRoC MH_03 (the paper's native ATE over the true MH_03 path, `trajectory_metrics.paper_mh03_anchor`):
the simulated odometry then leaves much less error for the graph to remove than a real filter does."""
MIN_RATIO_ODOMETRY_ATE_M = 1e-3
"""`--error-scales`: below this odometry ATE, and at k = 0 (the true poses, whose ATE is only the evaluation's
association floor), the ratios to it are not reported."""
MIN_DRIFT_PATH_M = 10.0
"""A drift per distance is reported (and judged) only over at least this much true path."""


@dataclass(frozen=True)
class Ablation:
    """One mapper configuration replayed on the tracking run."""

    key: str
    label: str
    conditioned: bool = True
    graph: bool = True
    revisits: bool = True
    drift_gate: bool = True
    depth_error_scale: float = 1.0


ABLATIONS: tuple[Ablation, ...] = (
    Ablation("davio", "DAVIO (complete)"),
    Ablation("no_conditioning", "w/o pose conditioning", conditioned=False),
    Ablation("graph_fixed", "graph poses fixed", graph=False),
    Ablation("no_revisits", "w/o revisits", revisits=False),
    Ablation("no_drift_gate", "w/o drift gate", drift_gate=False),
    # the emulator's sensitivity rows: every dense depth-error sigma of the emulated DA3 multiplied
    Ablation("depth_x2", "DAVIO, depth errors x2", depth_error_scale=2.0),
    Ablation("depth_x5", "DAVIO, depth errors x5", depth_error_scale=5.0),
    Ablation("depth_x20", "DAVIO, depth errors x20", depth_error_scale=20.0),
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from drivers.sim.imu_synth import IMU_PROFILES

    p.add_argument("--preset", action="append", default=None, metavar="NAME[:STYLE]",
                   help="motion preset with a synthetic IMU, optionally with a scene style (room, hall); "
                        f"repeatable (default: {', '.join(DEFAULT_PRESETS)}, {PRESET_SECONDS:g} s)")
    p.add_argument("--preset-imu", default=PRESET_IMU, choices=IMU_PROFILES,
                   help="the presets' synthetic IMU error model: the rig's datasheet densities, or those "
                        "plus the in-flight errors measured on the real EuRoC IMU (default %(default)s)")
    p.add_argument("--sequence", action="append", default=None, metavar="DIR[:STYLE]",
                   help="a euroc_imu_gt folder (repeatable; default: V1_02_medium and MH_03_medium from "
                        "../shared/data when present)")
    p.add_argument("--sequence-start", type=number_in(0, 1e7, unit=" s"), default=0.0, metavar="S",
                   help="seconds skipped at the start of every EuRoC-trajectory sequence")
    p.add_argument("--seconds", type=number, default=None,
                   help=f"cut every sequence to this length, s (default: whole sequences, presets "
                        f"{PRESET_SECONDS:g} s)")
    p.add_argument("--seed", type=count(0), default=0, help="simulation and emulated-DA3 seed")
    p.add_argument("--da3", default="base", help="emulated DA3 preset (small, base, large)")
    p.add_argument("--model-latency", type=number_in(0, 3600, unit=" s"), default=0.5, metavar="S",
                   help="sensor seconds between a mapping request and its result (FastClock)")
    p.add_argument("--config", metavar="TOML",
                   help="configuration of the run (see config.toml of a run; default: DavioConfig())")
    p.add_argument("--ablations", default=",".join(a.key for a in ABLATIONS),
                   help="comma-separated ablation rows to run (davio always runs)")
    p.add_argument("--error-scales", default="", metavar="K,...",
                   help="also replay the complete system with the odometry's error (every published and "
                        "window pose against the truth) multiplied by each K, e.g. 0.5,2,4 (default: none)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def sources(args: argparse.Namespace) -> tuple[list[Source], list[str]]:
    """The sequences named by the arguments and the messages of default sequences skipped (no data)."""
    out: list[Source] = []
    skipped: list[str] = []
    presets = args.preset if args.preset is not None else ([] if args.sequence else list(DEFAULT_PRESETS))
    for spec in presets:
        name, style = _split_style(spec)
        out.append(Source(f"preset {name} ({style})", "preset", name, style, imu_profile=args.preset_imu))
    start = args.sequence_start
    suffix = f", from {start:g} s" if start else ""
    if args.sequence:
        for spec in args.sequence:
            folder, style = _split_style(spec)
            label = Path(folder.rstrip("/")).name
            out.append(Source(f"{label} ({style}{suffix})", "euroc-trajectory", folder, style, start))
    elif args.preset is None:
        for folder, style in DEFAULT_SEQUENCES:
            if (SHARED / folder).is_dir():
                out.append(Source(f"{folder} ({style}{suffix})", "euroc-trajectory", str(SHARED / folder),
                                  style, start))
            else:
                skipped.append(f"{folder}: skipped, {SHARED / folder} is absent (the EuRoC-trajectory data "
                               "lives in ../shared/data/euroc_imu_gt beside the project)")
    return out, skipped


def _ablations(spec: str) -> list[Ablation]:
    from runtime.errors import ConfigError

    keys = [k.strip() for k in spec.split(",") if k.strip()]
    known = {a.key: a for a in ABLATIONS}
    bad = [k for k in keys if k not in known]
    if bad:
        raise ConfigError(f"--ablations: unknown {', '.join(bad)}; choose from {', '.join(known)}")
    return [a for a in ABLATIONS if a.key == "davio" or a.key in keys]


def _ate(traj: Any, gt: Any) -> tuple[float, Any]:
    from runtime.errors import DavioError
    from tools.evaluation import ate

    if len(traj) < 3:
        return float("nan"), None
    try:
        r = ate(traj, gt, align_method="se3")
    except DavioError:
        return float("nan"), None
    return float(r.trans["rmse"]), r


def _graph_counters(mapper: Any) -> dict:
    if mapper.backend is None:
        return {}
    st = mapper.backend.stats
    rv = st.revisits
    return {"solves": st.solves, "nodes": st.nodes, "evicted": st.evicted,
            "point_groups_adjacent": st.point_groups_adjacent,
            "point_groups_revisit": st.point_groups_revisit,
            "revisit_scale_links": st.revisit_scale_links, "revisits_attempted": rv.attempts,
            "revisits_accepted": rv.accepted, "revisit_point_groups": rv.point_groups,
            "revisits_rejected": {k: v for k, v in rv.rejected.items() if v}, "solve_s": st.solve_s,
            "solve_s_max": st.solve_s_max, "anchors_added": st.anchors_added,
            "candidates_low_overlap": st.candidates_low_overlap, "views_archived": st.views.archived,
            "views_thinned": st.views.thinned}


def _tracking_health(report: dict) -> dict:
    """The start-up and filter counters that explain a short or missing trajectory."""
    st, flt = report.get("startup", {}), report.get("filter", {})
    return {"published_by": st.get("published_by"),
            "restarts_after_divergence": st.get("restarts_after_divergence"),
            "divergence_reasons": flt.get("divergence_reasons", []),
            "initialized_at_end": flt.get("initialized"), "init_sources": flt.get("init_sources", {})}


def run_ablation(ab: Ablation, run: Any, ctx: dict) -> tuple[dict, Any]:
    """Replay one mapper configuration on the tracking run and score it; returns (row, Replay)."""
    from models.emulated_da3 import EmulatedDA3
    from runtime.mapping.mapper import Mapper
    from tools.benchmarks.mapping import evaluate
    from tools.benchmarks.mapping_scale import lambda_errors
    from tools.benchmarks.mapping_variants import depth_error_overrides, export_points
    from tools.benchmarks.trajectory_replay import replay, trajectory

    cfg, cam, truth, gt, idx = ctx["config"], ctx["camera"], ctx["truth"], ctx["gt"], ctx["idx"]
    overrides = depth_error_overrides(ctx["da3"], ab.depth_error_scale)
    model = EmulatedDA3(truth, cam.K, cam.width, cam.height, preset=ctx["da3"], seed=ctx["seed"], **overrides)
    revisits = replace(cfg.revisits, enabled=cfg.revisits.enabled and ab.revisits,
                       drift_gate=cfg.revisits.drift_gate and ab.drift_gate)
    mapper = Mapper(model, cam, cfg.mapping, matcher=ctx["matcher"], conditioned=ab.conditioned,
                    graph=cfg.graph if ab.graph and cfg.mapping.graph else False, revisits=revisits)
    rep = replay(run, mapper)
    causal_m, _ = _ate(trajectory(run.published, rep.causal, idx), gt)
    final_m, final_r = _ate(trajectory(run.published, rep.final, idx), gt)
    row: dict = {"label": ab.label, "causal_ate_m": causal_m, "final_ate_m": final_m,
                 "windows_offered": len(run.slots), "windows_accepted": mapper.stats.windows_accepted,
                 "rejected": dict(mapper.stats.windows_rejected), "commits_applied_live": rep.applied,
                 "mapping_s": rep.seconds, "graph": _graph_counters(mapper),
                 "depth_error_scale": ab.depth_error_scale, "emulator_overrides": overrides}
    ref = ctx.get("reference")
    subs = [s for s in rep.submaps if s.segment == ctx["segment"]]
    if ref is not None and subs and final_r is not None:
        pts = export_points(subs, cfg.mapping.voxel_m)
        al = final_r.alignment
        row["surface"] = evaluate(pts @ al.R.T + al.t, ref)
    if subs and ab.graph:
        row["lambda"] = lambda_errors(subs, truth, cam.width, cam.height)
    return row, rep


def run_sequence(src: Source, args: argparse.Namespace, log: Any = None) -> dict:
    """Track once, replay every mapper configuration and score one sequence; returns its JSON object."""
    from models.matcher import Matcher
    from runtime.config import DavioConfig, load_davio_config
    from tools.benchmarks.mapping import reference_cloud
    from tools.benchmarks.mapping_inputs import CachedTruth, SharedMatcher
    from tools.benchmarks.trajectory_inputs import record_tracking
    from tools.benchmarks.trajectory_metrics import coverage, first_state_s, odometry_drift
    from tools.benchmarks.trajectory_replay import odometry_poses, trajectory

    t0 = time.perf_counter()
    seconds = args.seconds if args.seconds is not None else (PRESET_SECONDS if src.kind == "preset" else None)
    rec = src.make(seconds, args.seed)
    cam = rec.rig.camera
    cfg = load_davio_config(args.config) if args.config else DavioConfig()
    run = record_tracking(rec, cfg, args.model_latency)
    gt = rec.groundtruth()
    pub = run.published
    out: dict = {"name": src.name, "source": rec.info, "frames": run.frames, "published": len(pub),
                 "sequence_s": (run.last_t_ns - run.first_t_ns) * 1e-9, "tracking_s": run.tracking_s,
                 "windows_offered": run.windows_offered, "windows_dropped": run.windows_dropped,
                 "windows_processed": len(run.slots), "tracking": _tracking_health(run.report)}
    if len(pub) < 3:
        out["error"] = f"the tracking run published {len(pub)} poses: nothing to score"
        return out
    segs = np.array([p.segment for p in pub])
    segment = int(segs[-1])
    idx = np.nonzero(segs == segment)[0]
    out["segments"] = int(len(np.unique(segs)))
    out["scored_segment"] = {"segment": segment, "poses": int(len(idx))}
    cov = coverage(np.array([p.t_ns for p in pub], np.int64), run.first_t_ns, run.last_t_ns)
    t_f = first_state_s(run.first_publish_t_ns, run.first_t_ns)
    odo = trajectory(pub, odometry_poses(pub), idx)
    odo_m, _ = _ate(odo, gt)
    out["drift"] = odometry_drift(odo, gt, odo_m)
    if log:
        d = out["drift"]
        log(f"{src.name}: tracked {run.frames} frames in {run.tracking_s:.0f} s, {len(run.slots)} windows, "
            f"odometry ATE {odo_m:.3f} m, drift {d['percent']:.2f} % of {d['path_m']:.0f} m")
    truth = CachedTruth(rec.gt_source)
    ctx = {"config": cfg, "camera": cam, "truth": truth, "gt": gt, "idx": idx, "segment": segment,
           "da3": args.da3, "seed": args.seed, "matcher": SharedMatcher(Matcher.default(top_k=1024))}
    stamps = run.keyframe_t_ns(segment)
    if stamps.size:
        ctx["reference"], out["reference"] = reference_cloud(rec, truth, stamps, cam)
    rows: dict = {}
    for ab in _ablations(args.ablations):
        row, _ = run_ablation(ab, run, ctx)
        rows[ab.key] = row
        if log:
            f10 = row.get("surface", {}).get("f10", float("nan"))
            log(f"  {ab.label:24s} final ATE {row['final_ate_m']:.3f} m  causal {row['causal_ate_m']:.3f} m  "
                f"F@10 {f10:.3f}  windows {row['windows_accepted']}/{row['windows_offered']}  "
                f"{row['mapping_s']:.0f} s" + (f"  lambda - lambda* RMS {row['lambda']['rms_error']:.3f}"
                                                if row.get("lambda", {}).get("submaps") else ""))
    if args.error_scales:
        from tools.benchmarks.trajectory_error_scale import parse_error_scales

        out["error_scales"] = error_scale_rows(run, rec, ctx, parse_error_scales(args.error_scales), log)
    davio = rows["davio"]
    out["trajectory"] = {
        "odometry": {"ate_m": odo_m, "ratio": 1.0},
        "causal": {"ate_m": davio["causal_ate_m"], "ratio": davio["causal_ate_m"] / odo_m},
        "final": {"ate_m": davio["final_ate_m"], "ratio": davio["final_ate_m"] / odo_m},
        "coverage": cov, "T_f_s": t_f}
    out["ablations"] = rows
    out["goals"] = goals(out["trajectory"])
    out["wall_s"] = time.perf_counter() - t0
    return out


def error_scale_rows(run: Any, rec: Any, ctx: dict, scales: list[float], log: Any = None) -> dict:
    """The complete system on `run` with the odometry's error multiplied by each k (module docstring, 5)."""
    from tools.benchmarks.trajectory_error_scale import error_scaled_run
    from tools.benchmarks.trajectory_replay import odometry_poses, trajectory

    out: dict = {}
    for k in scales:
        scaled = error_scaled_run(run, ctx["truth"].camera_pose, rec.rig.T_IC, k)
        odo_m, _ = _ate(trajectory(scaled.published, odometry_poses(scaled.published), ctx["idx"]), ctx["gt"])
        row, _ = run_ablation(ABLATIONS[0], scaled, ctx)
        g = row["graph"]
        defined = k > 0 and odo_m >= MIN_RATIO_ODOMETRY_ATE_M
        out[f"{k:g}"] = {"k": k, "odometry_ate_m": odo_m, "final_ate_m": row["final_ate_m"],
                         "causal_ate_m": row["causal_ate_m"],
                         "final_ratio": row["final_ate_m"] / odo_m if defined else None,
                         "causal_ratio": row["causal_ate_m"] / odo_m if defined else None,
                         "revisits_accepted": g.get("revisits_accepted"),
                         "revisits_attempted": g.get("revisits_attempted"),
                         "revisit_point_groups": g.get("revisit_point_groups"),
                         "f10": row.get("surface", {}).get("f10")}
        if log:
            r = out[f"{k:g}"]
            ratios = (f" ({r['final_ratio']:.3f} and {r['causal_ratio']:.3f} of the odometry)"
                      if defined else "")
            log(f"  odometry error x{k:g}: odometry ATE {odo_m:.4f} m, final {r['final_ate_m']:.4f} m, "
                f"causal {r['causal_ate_m']:.4f} m{ratios}")
    return out


def goals(traj: dict) -> dict:
    """The two goal checks of one sequence."""
    f, c = traj["final"]["ratio"], traj["causal"]["ratio"]
    return {"final_over_odometry": {"value": f, "target": f"<= {GOAL_FINAL_RATIO}",
                                    "met": bool(f <= GOAL_FINAL_RATIO)},
            "causal_over_odometry": {"value": c, "target": f"<= {GOAL_CAUSAL_RATIO:g}",
                                     "met": bool(c <= GOAL_CAUSAL_RATIO)}}


def easy(seq: dict, refs: dict) -> bool | None:
    """`EASY_FRACTION`'s verdict for one sequence (None without the reference or a long enough path)."""
    ref = refs.get("paper_openvins_mh03")
    d = seq.get("drift")
    if ref is None or d is None or d["path_m"] < MIN_DRIFT_PATH_M:
        return None
    return bool(d["ate_percent_of_path"] < EASY_FRACTION * ref["ate_percent_of_path"])


def anchors() -> dict:
    """OpenVINS's drift figures from the shared data (tools/benchmarks/trajectory_metrics.py)."""
    from tools.benchmarks.trajectory_metrics import openvins_sim_anchor, paper_mh03_anchor

    out = {}
    sim = openvins_sim_anchor(OPENVINS_SIM)
    if sim is not None:
        out["openvins_sim"] = sim
    mh03 = SHARED / "MH_03_medium" / "groundtruth_tum.txt"
    if mh03.is_file():
        from tools.evaluation import read_trajectory

        out["paper_openvins_mh03"] = paper_mh03_anchor(read_trajectory(mh03))
    return out


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError
    from tools.benchmarks.trajectory_error_scale import parse_error_scales

    _ablations(args.ablations)
    parse_error_scales(args.error_scales)
    from models.emulated_da3 import make_params

    make_params(args.da3)   # an unknown preset fails before the slow part
    srcs, skipped = sources(args)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    for msg in skipped:
        log(msg)
    if not srcs:
        raise ConfigError("no sequence to run (give --preset or --sequence)")
    t0 = time.perf_counter()
    refs = anchors()
    seqs = {src.name: run_sequence(src, args, log) for src in srcs}
    for s in seqs.values():
        s["easy"] = easy(s, refs)
    met = [g["met"] for s in seqs.values() for g in s.get("goals", {}).values()]
    result = {"benchmark": NAME, "emulated": True, "emulated_da3": args.da3, "seconds": args.seconds,
              "seed": args.seed, "model_latency_s": args.model_latency, "sequences": seqs, "skipped": skipped,
              "anchors": refs, "goals_met": bool(met) and all(met), "wall_s": time.perf_counter() - t0}
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=2))
    if args.json:
        print(strict_dumps(result))
        return 0
    from tools.benchmarks.trajectory_report import print_tables

    print_tables(result)
    return 0
