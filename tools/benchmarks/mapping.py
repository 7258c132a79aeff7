"""`davio bench mapping`: dense-map accuracy of DAVIO's mapper against its references (paper Sec. VI-VII).

For each simulated sequence (motion presets with a synthetic IMU, and images rendered along real
EuRoC trajectories with the real IMU), cut to `--seconds`:
  1. the recording is tracked once with the native initializer and mapping off; the published
     poses give the keyframe windows (mapping_inputs.py), identical for every variant;
  2. each variant (mapping_variants.py: a DAVIO, b unconditioned reference, c ScaRF-style,
     d DAVIO on true poses, e DAVIO without the conditioning benefit, f DAVIO with depth errors x2,
     g DAVIO with the submap graph off, h the unconditioned reference with upper-bound pose errors,
     i DAVIO with true poses within each window: a diagnosis, j DAVIO with the paper's strict
     multi-view rule)
     maps them with a fresh emulated DA3 of the same seed;
  3. evaluation as the paper: VIO-pose maps (in the odometry frame: the mapper's submap poses are
     the filter's) are moved by the rigid (SE(3), no scale, no ICP) alignment of the VIO trajectory
     to the ground truth; true-pose maps are not moved; the reference is the scene's surface
     sampled at 2 cm, restricted to the points visible from the keyframes' true cameras
     (tools/evaluation/visibility.py); both clouds are voxelised at 4 cm and scored at 10 cm:
     mean map-to-reference distance, completeness (reference-to-map distance, median as in the
     paper's ablation table, mean in the JSON), precision, recall and F@10.
Goals per sequence: F@10(a) - F@10(c) >= 0.1, mean(a) <= 0.8 mean(c), F@10(a) > F@10(b).
Everything is simulated: the depth model is the emulated DA3 (models/emulated_da3), not DA3.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.benchmarks.mapping_variants import VARIANT_KEYS
from tools.cli_types import count, number, number_in

NAME = "mapping"
HELP = ("dense mapping on simulated sequences: DAVIO vs unconditioned, ScaRF-style, true poses and "
        "ablations (mean distance, precision, recall, F@10)")
DESCRIPTION = __doc__

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "euroc_imu_gt"
DEFAULT_PRESETS = ("euroc", "euroc:hall")
DEFAULT_SEQUENCES: tuple[tuple[str, str, float], ...] = (("V1_02_medium", "room", 0.0),
                                                         ("MH_03_medium", "hall", 10.0))
"""EuRoC-trajectory defaults: (folder under shared/data/euroc_imu_gt, scene style, start s). MH_03
starts at 10 s: its first 10 s are hand-held excitation, then it rests before take-off."""

REF_SPACING_M = 0.02
VOXEL_M = 0.04
THRESHOLD_M = 0.10
GOAL_F10_MARGIN = 0.1
GOAL_MEAN_RATIO = 0.8


def add_arguments(p: argparse.ArgumentParser) -> None:
    from drivers.sim.imu_synth import IMU_PROFILES

    p.add_argument("--preset", action="append", default=None, metavar="NAME[:STYLE]",
                   help="motion preset with a synthetic IMU, optionally with a scene style (room, hall); "
                        "repeatable (default: euroc and euroc:hall)")
    p.add_argument("--preset-imu", default="datasheet", choices=IMU_PROFILES,
                   help="the presets' synthetic IMU errors: the rig's datasheet densities (default), or "
                        "those plus the in-flight errors measured on the real EuRoC IMU")
    p.add_argument("--sequence", action="append", default=None, metavar="DIR[:STYLE]",
                   help="a euroc_imu_gt folder (EuRoC-trajectory mode; repeatable; default: V1_02_medium "
                        "and MH_03_medium from ../shared/data when present)")
    p.add_argument("--sequence-start", type=number_in(0, 1e7, unit=" s"), default=0.0, metavar="S",
                   help="seconds skipped at the start of every --sequence")
    p.add_argument("--seconds", type=number, default=20.0, help="length of each sequence, s")
    p.add_argument("--seed", type=count(0), default=0, help="simulation and emulated-DA3 seed")
    p.add_argument("--da3", default="base", help="emulated DA3 preset (small, base, large)")
    p.add_argument("--variants", default=VARIANT_KEYS, help="rows to run (letters a-j, module docstring)")
    p.add_argument("--paper-gauge", action="store_true",
                   help="the graph fixes the first submap's lambda at 0, as the paper (GraphConfig."
                        "gauge_lambda_free = false; default: estimated under the scale prior as every "
                        "node's)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def graph_config(args: argparse.Namespace) -> Any:
    """The GraphConfig the arguments ask for (None: the default)."""
    if not getattr(args, "paper_gauge", False):
        return None
    from runtime.graph.config import GraphConfig

    return GraphConfig(gauge_lambda_free=False)


@dataclass(frozen=True)
class Source:
    """A sequence of the benchmark: its name and how to simulate it."""

    name: str
    kind: str            # "preset" | "euroc-trajectory"
    what: str            # preset name or folder
    style: str
    start_s: float = 0.0
    imu_profile: str = "datasheet"   # presets: the synthetic IMU's error model (SimConfig.imu_profile)

    def make(self, seconds: float, seed: int) -> Any:
        from drivers.sim import SimConfig, SimRecording

        if self.kind == "preset":
            return SimRecording.from_preset(SimConfig(preset=self.what, seconds=seconds, seed=seed,
                                                      style=self.style, imu_profile=self.imu_profile))
        cfg = SimConfig(seconds=seconds, seed=seed, style=self.style, start_s=self.start_s)
        return SimRecording.from_euroc_imu_gt(self.what, cfg)


def _split_style(spec: str) -> tuple[str, str]:
    head, sep, style = spec.rpartition(":")
    return (head, style) if sep and style in ("room", "hall") else (spec, "room")


def sources(args: argparse.Namespace) -> list[Source]:
    """The sequences named by the arguments (defaults: module constants)."""
    out = []
    presets = args.preset if args.preset is not None else ([] if args.sequence else list(DEFAULT_PRESETS))
    for spec in presets:
        name, style = _split_style(spec)
        out.append(Source(f"preset {name} ({style})", "preset", name, style,
                          imu_profile=args.preset_imu))
    if args.sequence:
        for spec in args.sequence:
            folder, style = _split_style(spec)
            label = Path(folder.rstrip("/")).name
            start = f", from {args.sequence_start:g} s" if args.sequence_start else ""
            out.append(Source(f"{label} ({style}{start})", "euroc-trajectory", folder, style,
                              args.sequence_start))
    elif args.preset is None:
        for folder, style, start in DEFAULT_SEQUENCES:
            if (SHARED / folder).is_dir():
                suffix = f", from {start:g} s" if start else ""
                out.append(Source(f"{folder} ({style}{suffix})", "euroc-trajectory", str(SHARED / folder),
                                  style, start))
    return out


def reference_cloud(rec: Any, truth: Any, stamps: np.ndarray, camera: Any) -> tuple[np.ndarray, dict]:
    """The reference: surface points (2 cm) visible from the true cameras at `stamps`, voxelised at 4 cm."""
    from tools.evaluation import voxel_downsample
    from tools.evaluation.visibility import visible_points

    pts = rec.scene.surface_points(REF_SPACING_M)[0]
    views = [truth.render_view(int(t), camera.K, camera.width, camera.height) for t in stamps]
    vis = visible_points(pts, np.stack([v.T_WC for v in views]), np.stack([v.depth for v in views]),
                         camera.K)
    ref = voxel_downsample(pts[vis], VOXEL_M)
    return ref, {"surface_points": int(len(pts)), "visible_points": int(vis.sum()),
                 "reference_voxels": int(len(ref)), "views": int(len(stamps))}


def evaluate(points_W: np.ndarray, ref_vox: np.ndarray) -> dict:
    """Surface metrics of a map (world frame) against the voxelised reference (module docstring)."""
    from tools.evaluation import surface_metrics, voxel_downsample

    pts = np.asarray(points_W, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        nan = float("nan")
        return {"mean_m": nan, "median_m": nan, "completeness_m": nan, "completeness_median_m": nan,
                "precision": 0.0, "recall": 0.0, "f10": 0.0, "points": 0}
    r = surface_metrics(voxel_downsample(pts, VOXEL_M), ref_vox, threshold_m=THRESHOLD_M)
    return {"mean_m": r.accuracy_m, "median_m": r.accuracy_median_m, "completeness_m": r.completeness_m,
            "completeness_median_m": r.completeness_median_m, "precision": r.precision, "recall": r.recall,
            "f10": r.fscore, "points": r.n_rec}


def goals(rows: dict) -> dict:
    """The three goal checks of one sequence (those whose rows were run)."""
    out = {}
    a, b, c = rows.get("a"), rows.get("b"), rows.get("c")
    if a and c:
        d = a["f10"] - c["f10"]
        out["f10_a_minus_c"] = {"value": d, "target": f">= {GOAL_F10_MARGIN}",
                                "met": bool(d >= GOAL_F10_MARGIN)}
        ratio = a["mean_m"] / c["mean_m"] if c["mean_m"] > 0 else float("nan")
        out["mean_a_over_c"] = {"value": ratio, "target": f"<= {GOAL_MEAN_RATIO}",
                                "met": bool(ratio <= GOAL_MEAN_RATIO)}
    if a and b:
        d = a["f10"] - b["f10"]
        out["f10_a_minus_b"] = {"value": d, "target": "> 0", "met": bool(d > 0)}
    return out


def run_sequence(src: Source, args: argparse.Namespace, log: Any = None) -> dict:
    """Track, map with every variant and score one sequence; returns its JSON object."""
    from models.matcher import Matcher
    from runtime.mapping.config import MappingConfig
    from tools.benchmarks.mapping_inputs import CachedTruth, SharedMatcher, track
    from tools.benchmarks.mapping_scale import lambda_errors
    from tools.benchmarks.mapping_variants import VARIANTS, run_variant

    t0 = time.perf_counter()
    mapping = MappingConfig()
    rec = src.make(args.seconds, args.seed)
    cam = rec.rig.camera
    inputs = track(rec, mapping)
    if log:
        log(f"{src.name}: tracked {inputs.frames} frames in {inputs.tracking_s:.1f} s, "
            f"{len(inputs.windows)} windows, VIO ATE {inputs.vio_ate_m:.3f} m")
    truth = CachedTruth(rec.gt_source)
    ref, ref_info = reference_cloud(rec, truth, inputs.keyframe_t_ns, cam)
    matcher = SharedMatcher(Matcher.default(top_k=1024))
    rows: dict[str, dict] = {}
    for v in VARIANTS:
        if v.key not in args.variants:
            continue
        r = run_variant(v, inputs, truth, cam, mapping, args.da3, args.seed, matcher, graph_config(args))
        pts = r.points if v.poses == "gt" else inputs.to_world(r.points)
        row = {"label": v.label, **evaluate(pts, ref),
               "raw_points": int(len(r.points)), "windows_offered": r.offered, "windows_accepted": r.accepted,
               "rejected": r.rejected, "mapping_s": r.seconds, "emulator_overrides": r.overrides}
        if r.submaps:
            row["lambda"] = lambda_errors(r.submaps, truth, cam.width, cam.height)
        rows[v.key] = row
        if log:
            lam = row.get("lambda", {})
            scales = (f"  lambda - lambda* RMS {lam['rms_error']:.3f} "
                      f"(lambda = 0: {lam['rms_error_lambda_zero']:.3f})" if lam.get("submaps") else "")
            log(f"  ({v.key}) {v.label:32s} mean {row['mean_m']:.3f} m  F@10 {row['f10']:.3f}  "
                f"windows {r.accepted}/{r.offered}  {r.seconds:.1f} s{scales}")
    return {"name": src.name, "source": rec.info, "frames": inputs.frames, "published": inputs.published,
            "segments": inputs.segments, "windows": len(inputs.windows), "vio_ate_m": inputs.vio_ate_m,
            "keyframes": int(len(inputs.keyframe_t_ns)), "reference": ref_info, "rows": rows,
            "goals": goals(rows), "tracking_s": inputs.tracking_s, "wall_s": time.perf_counter() - t0}


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError

    bad = set(args.variants) - set(VARIANT_KEYS)
    if bad or not args.variants:
        raise ConfigError(f"--variants takes letters from {VARIANT_KEYS}, got {args.variants!r}")
    from models.emulated_da3 import make_params

    make_params(args.da3)  # an unknown preset fails before the slow part
    srcs = sources(args)
    if not srcs:
        raise ConfigError("no sequence to run (give --preset or --sequence)")

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    seqs = {}
    for src in srcs:
        seqs[src.name] = run_sequence(src, args, log)
    met = [g["met"] for s in seqs.values() for g in s["goals"].values()]
    result = {"benchmark": NAME, "emulated": True, "emulated_da3": args.da3, "seconds": args.seconds,
              "gauge_lambda_free": not bool(args.paper_gauge),
              "seed": args.seed, "threshold_m": THRESHOLD_M, "voxel_m": VOXEL_M,
              "reference_spacing_m": REF_SPACING_M, "sequences": seqs,
              "goals_met": bool(met) and all(met), "wall_s": time.perf_counter() - t0}
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=2))
    if args.json:
        print(strict_dumps(result))
        return 0
    _print_tables(result)
    return 0


def _print_tables(result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(width=max(Console().width, 132))
    for name, s in result["sequences"].items():
        t = Table(title=f"{name}: {s['windows']} windows, VIO ATE {s['vio_ate_m']:.3f} m, reference "
                        f"{s['reference'].get('reference_voxels', 0)} voxels "
                        f"(emulated DA3 {result['emulated_da3']})")
        for c in ("variant", "mean (m)", "compl. med (m)", "precision", "recall", "F@10", "points",
                  "windows"):
            t.add_column(c)
        for key, r in s["rows"].items():
            t.add_row(f"({key}) {r['label']}", f"{r['mean_m']:.3f}", f"{r['completeness_median_m']:.3f}",
                      f"{r['precision']:.3f}", f"{r['recall']:.3f}", f"{r['f10']:.3f}", str(r["points"]),
                      f"{r['windows_accepted']}/{r['windows_offered']}")
        con.print(t)
        for gname, g in s["goals"].items():
            con.print(f"  goal {gname} {g['target']}: {g['value']:.3f} {'met' if g['met'] else 'NOT met'}")
    con.print(f"all goals met: {result['goals_met']}  (wall {result['wall_s']:.0f} s)")
