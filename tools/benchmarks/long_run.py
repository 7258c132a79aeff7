"""`davio bench long-run`: what grows with a run's length, per hour of operation, measured in one process.

What grows with time however bounded the map and the graph are:
  * the published states a run keeps for `odometry.tum`, `causal.tum` and the final re-export: bytes per
    pose (tracemalloc) of the pipeline's columns (`runtime.pose_history.PoseHistory`) against the same
    states kept as Python objects (a `Published` with its covariance and the (T_MI, version, fraction)
    tuple, as the pipeline kept them before), and per hour at --camera-hz;
  * the map archive's manifest (`tools.map_archive.MapArchiveWriter`) with N submaps archived, N = hours x
    3600 / 1.5 (a submap every 1.5 s): one journal cycle, from manifest.json written whole through commits
    (one new submap, --moved others moved, one pair record), each a journal line, to the next whole write:
    time a commit and bytes written a commit on average, against writing the whole manifest at every
    commit (what the writer did before the journal); and the writer's memory a submap (tracemalloc over
    --writer-submaps submaps committed 50 at a time), against the encoded texts it must keep;
  * the whole tracking pipeline (`--track-seconds S`, 0 = skip): a simulated `euroc` preset recording
    through `runtime.pipeline.VioPipeline` (native start-up, no model, so no map) with tracemalloc on; the
    least-squares slope of the traced bytes against the poses published, over the second half of the run.
    (A `Session` adds its `poses()` queue, capped at 12000 poses, about 11 MB, full after ten minutes.)
Submaps carry 50 points here (the manifest does not hold points; a real submap's npz is about 0.9 MB).
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, number

NAME = "long-run"
HELP = ("per-hour growth: bytes per published pose, the map archive writer's memory per submap, and "
        "the manifest's commit time by archive size")
DESCRIPTION = __doc__
SUBMAP_PERIOD_S = 1.5
"""A submap every 1.5 s: 0.5 s keyframes, five-image windows sharing two images (paper Sec. III)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--hours", default="0.25,1,2,4", help="comma-separated run lengths for the manifest rows")
    p.add_argument("--camera-hz", type=number, default=20.0,
                   help="published poses per second (a pose a frame)")
    p.add_argument("--poses", type=count(100), default=20000, help="poses measured for the bytes per pose")
    p.add_argument("--moved", type=count(0), default=63,
                   help="submaps a commit moves besides the new one (default: the graph's other nodes, "
                   "graph.max_resident_nodes - 1)")
    p.add_argument("--writer-submaps", type=count(200, 100_000), default=1000,
                   help="submaps archived for the writer's memory a submap (200 to 100000; default 1000)")
    p.add_argument("--track-seconds", type=number, default=300.0,
                   help="length of the simulated tracking run measured whole (0 = skip)")
    p.add_argument("--seed", type=count(0), default=0, help="seed of that recording")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def _hours(text: str) -> list[float]:
    try:
        hs = [float(h) for h in text.split(",") if h.strip()]
    except ValueError as exc:
        raise SystemExit(f"davio bench long-run: --hours must be numbers, got {text!r}") from exc
    if not hs or not all(math.isfinite(h) and 0 < h <= 24 for h in hs):
        raise SystemExit(f"davio bench long-run: --hours must lie in (0, 24], got {text!r}")
    return hs


def _states(n: int, rng: np.random.Generator) -> list:
    from scipy.spatial.transform import Rotation

    from runtime.startup import Published

    R = Rotation.random(n, random_state=int(rng.integers(1 << 30))).as_matrix()
    out = []
    for k in range(n):
        B = rng.normal(size=(6, 6))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[k], rng.normal(size=3)
        p = Published(10**18 + 50_000_000 * k, 10**18 + 50_000_000 * k, R[k], rng.normal(size=3),
                      rng.normal(size=3), ("native:dynamic", "feedforward")[k % 2], 0, 0, B @ B.T)
        out.append((p, T, k // 30, float(rng.uniform())))
    return out


def pose_bytes(n: int, seed: int = 0) -> dict:
    """Bytes per pose (tracemalloc) of n published states as objects and in the pipeline's columns."""
    from runtime.pose_history import PoseHistory
    from runtime.startup import Published

    states = _states(n, np.random.default_rng(seed))
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        kept = [(Published(p.t_ns + 0, p.t_cam_ns + 0, p.R_OI.copy(), p.p_OI.copy(), p.v_OI.copy(),
                           p.source, p.filter_id, p.segment, p.covariance.copy()), (T.copy(), v, f))
                for p, T, v, f in states]
        objects = tracemalloc.get_traced_memory()[0] - base
        del kept
        base = tracemalloc.get_traced_memory()[0]
        h = PoseHistory()
        for p, T, v, f in states:
            h.append(p, T, v, f)
        columns = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    return {"poses": n, "objects_bytes_per_pose": objects / n, "columns_bytes_per_pose": columns / n}


def tracking_growth(seconds: float, seed: int, progress: bool) -> dict:
    """Traced bytes the tracking pipeline holds, per published pose, over the second half of a run: the
    pipeline driven event by event on this thread (no queue between the events and the pipeline), the
    traced size read after every frame's state is published, slope by least squares."""
    from drivers.sim import SimConfig, SimRecording
    from runtime.config import DavioConfig
    from runtime.events import Frame
    from runtime.pipeline import VioPipeline

    rec = SimRecording.from_preset(SimConfig(preset="euroc", seconds=seconds, seed=seed))
    pipe = VioPipeline(rec.rig, None, DavioConfig())
    samples: list[tuple[float, int, int]] = []      # (sensor s, published poses, traced bytes)
    t0 = None
    next_report = 0.5 * seconds
    tracemalloc.start()
    try:
        for ev in rec.events():
            t0 = ev.t_ns if t0 is None else t0
            s = (ev.t_ns - t0) * 1e-9
            out = pipe.on_frame(ev) if isinstance(ev, Frame) else pipe.on_imu(ev)
            if out and s >= 0.5 * seconds:
                samples.append((s, len(pipe.published), tracemalloc.get_traced_memory()[0]))
                if progress and s >= next_report:
                    print(f"  tracking run: t = {s:5.1f} s, {samples[-1][1]} poses, "
                          f"{samples[-1][2] / 1e6:.2f} MB traced", flush=True)
                    next_report += 0.1 * seconds
    finally:
        tracemalloc.stop()
    if len(samples) < 10:
        return {"seconds": seconds, "seed": seed, "poses_second_half": len(samples),
                "traced_bytes_per_pose": None, "stderr_bytes_per_pose": None}
    a = np.array(samples, np.float64)
    (slope, icpt), cov = np.polyfit(a[:, 1], a[:, 2], 1, cov=True)
    return {"seconds": seconds, "seed": seed, "poses_second_half": int(a[-1, 1] - a[0, 1]),
            "traced_bytes_per_pose": float(slope), "stderr_bytes_per_pose": float(np.sqrt(cov[0, 0])),
            "traced_mb_first": float(a[0, 2] / 1e6), "traced_mb_last": float(a[-1, 2] / 1e6),
            "traced_mb_max": float(a[:, 2].max() / 1e6)}


def _submap(index: int, rng: np.random.Generator) -> Any:
    from runtime.mapping.submap import Submap

    n_img, n_pts = 5, 50
    T_SC = np.tile(np.eye(4), (n_img, 1, 1))
    T_SC[:, :3, 3] = rng.normal(0, 0.2, (n_img, 3))
    T = np.eye(4)
    T[:3, 3] = rng.normal(0, 5, 3)
    fit = {"baseline_m": float(rng.uniform(0.1, 1)), "fit_rmse_m": float(rng.uniform(0, 0.05)),
           "log_s_hat": float(rng.normal(0, 0.05)), "window_id": index,
           "frame_scale_rms_before": float(rng.uniform(0, 0.05)),
           "frame_scale_rms_after": float(rng.uniform(0, 0.02)),
           "frame_scale_matches": int(rng.integers(100, 900))}
    return Submap(index=index, frame_t_ns=10**18 + np.arange(n_img, dtype=np.int64) * 500_000_000 + index,
                  centre=2, T_OS=T, T_SC=T_SC, K=np.array([[400.0, 0, 250], [0, 400.0, 180], [0, 0, 1]]),
                  s_hat=1.0, frame_scales=np.ones(n_img),
                  points_C=rng.uniform(0.5, 3, (n_pts, 3)).astype(np.float32),
                  image=rng.integers(0, n_img, n_pts).astype(np.uint8), conf=np.ones(n_pts, np.float32),
                  grey=rng.integers(0, 256, n_pts).astype(np.uint8), T_MS=T.copy(), lam=0.0,
                  version=index + 1, fit=fit)


def _pair(a: int, rng: np.random.Generator) -> dict:
    return {"a": a, "b": a + 1, "kappa": float(rng.normal(0, 0.03)), "sigma": 0.03, "method": "shared",
            "n_images": 2, "n_pixels": int(rng.integers(10**5, 10**6)), "m": rng.normal(0, 0.03, 2).tolist()}


def _whole_manifest(w: Any, pairs: list, version: int, stats: dict) -> dict:
    """The whole manifest of writer `w`'s state, built here from its entries and the commit's arguments."""
    from tools.map_archive.format import FORMAT, SCHEMA_VERSION, davio_version, jsonable

    return {"format": FORMAT, "schema_version": SCHEMA_VERSION, "created_by": davio_version(),
            "archive_id": w.archive_id, **w.header, "map_version": version,
            "journal_generation": w.generation, "submaps": w.entries, "pairs": jsonable(list(pairs)),
            "stats": jsonable(dict(stats))}


def writer_bytes(n_submaps: int, header: dict) -> dict:
    """The map archive writer's traced memory a submap over commits of 50 submaps (one pair record a submap)
    after the first, `n_submaps` in all, against the bytes of the entry and pair texts a whole write joins
    (what it must keep)."""
    from tools.map_archive import MapArchiveWriter

    rng = np.random.default_rng(1)
    subs = [_submap(k, rng) for k in range(n_submaps)]
    pairs = [_pair(k, rng) for k in range(n_submaps)]
    with tempfile.TemporaryDirectory(prefix="davio-long-run-") as tmp:
        tracemalloc.start()
        try:
            w = MapArchiveWriter(Path(tmp) / "map", header)
            w.commit(subs[:50], pairs[:50], 1, {})     # the first commit's imports and caches not counted
            base = tracemalloc.get_traced_memory()[0]
            texts0 = _texts(w)
            for k0 in range(50, n_submaps, 50):
                w.commit(subs[k0:k0 + 50], pairs[:k0 + 50], k0 + 1, {})
            traced = tracemalloc.get_traced_memory()[0] - base
        finally:
            tracemalloc.stop()
        n = n_submaps - 50
    return {"submaps": n_submaps, "traced_bytes_per_submap": traced / n,
            "text_bytes_per_submap": (_texts(w) - texts0) / n}


def _texts(w: Any) -> int:
    """Characters of the encoded entry and pair texts writer `w` holds."""
    return sum(len(t) for t in w._entry_text.values()) + sum(len(t) for t in w._pair_text)


def manifest_cycle(n_submaps: int, moved: int, header: dict, progress: bool,
                   max_commits: int = 20000) -> dict:
    """One journal cycle of the map archive with n_submaps archived: from a manifest.json just written
    whole, commits (one new submap, `moved` others moved, one pair record) until the writer writes it whole
    again. Returns the commits, their median and mean seconds, the whole write's seconds, bytes written a
    commit on average (journal lines and the whole write), the manifest's size (what every commit wrote
    before the journal), and whether the archive reads back as the whole manifest built here
    (`reads_back`, after the cycle's last journal line) and, written whole at the end, has its text
    (`same_text`)."""
    from tools.map_archive import MapArchiveWriter, read_manifest

    rng = np.random.default_rng(n_submaps)
    with tempfile.TemporaryDirectory(prefix="davio-long-run-") as tmp:
        w = MapArchiveWriter(Path(tmp) / "map", header)
        subs = [_submap(k, rng) for k in range(n_submaps)]
        pairs = [_pair(k, rng) for k in range(n_submaps)]
        t_fill = time.perf_counter()
        for k0 in range(0, n_submaps, 200):          # archive the first n (200 submaps per commit)
            w.commit(subs[k0:min(k0 + 200, n_submaps)], pairs[:min(k0 + 200, n_submaps)], k0 + 1, {})
            if progress and time.perf_counter() - t_fill > 10:
                print(f"  archiving {min(k0 + 200, n_submaps)} / {n_submaps} submaps", flush=True)
                t_fill = time.perf_counter()
        w.close()
        manifest_bytes, written0, whole0 = w.manifest_bytes, w.bytes_written, w.whole_writes
        times, reads_back = [], None
        stats: dict = {}
        while w.whole_writes == whole0 and len(times) < max_commits:
            j = len(subs)
            subs.append(_submap(j, rng))
            moved_subs = [subs[int(i)] for i in rng.choice(j, min(moved, j), replace=False)]
            for sm in moved_subs:
                sm.T_MS = sm.T_MS.copy()
                sm.T_MS[:3, 3] += rng.normal(0, 0.01, 3)
                sm.version = j + 1
            pairs.append(_pair(j - 1, rng))
            stats = {"windows_offered": j, "windows_accepted": j, "rmse": 0.01}
            t0 = time.perf_counter()
            w.commit([subs[j], *moved_subs], pairs, j + 1, stats)
            times.append(time.perf_counter() - t0)
            if w.whole_writes == whole0 and w.journal_bytes * 2 > w.manifest_bytes and reads_back is None:
                info = read_manifest(w.folder)
                info.pop("journal")
                expected = _whole_manifest(w, pairs, j + 1, stats)
                reads_back = info == json.loads(json.dumps(expected, allow_nan=False))
        expected = _whole_manifest(w, pairs, len(subs), stats)
        same = (w.folder / "manifest.json").read_text() == json.dumps(expected, allow_nan=False, indent=1)
        cycle = len(times)
        written = w.bytes_written - written0
    return {"submaps": n_submaps, "manifest_mb": manifest_bytes / 1e6, "moved": moved, "cycle_commits": cycle,
            "complete_cycle": w.whole_writes > whole0, "commit_median_s": statistics.median(times),
            "commit_mean_s": statistics.fmean(times),
            "whole_write_s": times[-1] if w.whole_writes > whole0 else None,
            "bytes_per_commit": written / cycle, "whole_bytes_per_commit": manifest_bytes,
            "reads_back": bool(reads_back), "same_text": same}


def run(args: argparse.Namespace) -> int:
    hours = _hours(args.hours)
    if not (args.camera_hz > 0 and math.isfinite(args.camera_hz)):
        raise SystemExit(f"davio bench long-run: --camera-hz must be positive, got {args.camera_hz}")
    track_s = args.track_seconds
    if not (math.isfinite(track_s) and (track_s == 0 or 10 <= track_s <= 3600)):
        raise SystemExit(f"davio bench long-run: --track-seconds must be 0 or in [10, 3600], got "
                         f"{args.track_seconds}")
    from runtime.config import DavioConfig
    from runtime.config_io import config_to_dict

    progress = not args.json
    header = {"rig": {"camera": "pinhole"}, "model": {"description": "bench"},
              "config": config_to_dict(DavioConfig())}
    poses = pose_bytes(args.poses)
    per_hour = 3600 * args.camera_hz
    poses["objects_mb_per_hour"] = poses["objects_bytes_per_pose"] * per_hour / 1e6
    poses["columns_mb_per_hour"] = poses["columns_bytes_per_pose"] * per_hour / 1e6
    rows = []
    for h in hours:
        n = int(round(h * 3600 / SUBMAP_PERIOD_S))
        if progress:
            print(f"  manifest with {n} submaps ({h:g} h)", flush=True)
        rows.append({"hours": h, **manifest_cycle(n, args.moved, header, progress)})
    writer = writer_bytes(args.writer_submaps, header)
    writer["mb_per_hour"] = writer["traced_bytes_per_submap"] * 3600 / SUBMAP_PERIOD_S / 1e6
    tracking = tracking_growth(args.track_seconds, args.seed, progress) if args.track_seconds else None
    out = {"camera_hz": args.camera_hz, "poses": poses, "manifest": rows, "writer": writer,
           "submap_period_s": SUBMAP_PERIOD_S, "tracking": tracking}
    if args.out:
        Path(args.out).write_text(strict_dumps(out, indent=1))
    if args.json:
        print(strict_dumps(out, indent=1))
        return 0 if all(r["same_text"] and r["reads_back"] for r in rows) else 1
    print(f"published states ({args.poses} poses, tracemalloc): objects "
          f"{poses['objects_bytes_per_pose']:.0f} B/pose ({poses['objects_mb_per_hour']:.1f} MB/h at "
          f"{args.camera_hz:g} Hz), columns "
          f"{poses['columns_bytes_per_pose']:.0f} B/pose ({poses['columns_mb_per_hour']:.1f} MB/h)")
    if tracking is not None and tracking["traced_bytes_per_pose"] is not None:
        b = tracking["traced_bytes_per_pose"]
        print(f"tracking pipeline ({tracking['seconds']:g} s euroc preset, second half, "
              f"{tracking['poses_second_half']} poses): {b:.0f} +- {tracking['stderr_bytes_per_pose']:.0f} B "
              f"traced per published pose ({b * per_hour / 1e6:.1f} MB/h at {args.camera_hz:g} Hz)")
    per_h = 3600 / SUBMAP_PERIOD_S / 1e6
    print(f"map archive writer ({writer['submaps']} submaps, tracemalloc): "
          f"{writer['traced_bytes_per_submap']:.0f} B/submap ({writer['mb_per_hour']:.1f} MB/h at a submap "
          f"every {SUBMAP_PERIOD_S:g} s), of which the encoded texts {writer['text_bytes_per_submap']:.0f} B")
    print(f"map manifest: one journal cycle a size (a commit adds a submap and moves {args.moved}); "
          f"MB written an hour at a commit every {SUBMAP_PERIOD_S:g} s")
    print("| run length | submaps | manifest MB | commits a cycle | commit ms median / mean | "
          "whole write ms | MB/h journal | MB/h whole every commit | ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    if not all(r["same_text"] and r["reads_back"] for r in rows):
        print("ERROR: the archive does not read back as the whole manifest", flush=True)
        return 1
    for r in rows:
        cycle = f"{r['cycle_commits']}" + ("" if r["complete_cycle"] else " (cut)")
        whole = "-" if r["whole_write_s"] is None else f"{1e3 * r['whole_write_s']:.1f}"
        print(f"| {r['hours']:g} h | {r['submaps']} | {r['manifest_mb']:.1f} | {cycle} | "
              f"{1e3 * r['commit_median_s']:.1f} / {1e3 * r['commit_mean_s']:.1f} | "
              f"{whole} | "
              f"{r['bytes_per_commit'] * per_h:.0f} | {r['whole_bytes_per_commit'] * per_h:.0f} | "
              f"{r['bytes_per_commit'] / r['whole_bytes_per_commit']:.3f} |")
    return 0
