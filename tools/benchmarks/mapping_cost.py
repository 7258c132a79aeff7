"""`davio bench mapping-cost`: what mapping costs the tracker, how many windows the model worker
keeps up with, and whether memory stays flat.

Three parts (each optional):
  * `--arms`: the same recording (pre-rendered into memory, so rendering is not timed) replayed
    in real time (PacedClock) with mapping off and on, alternately: tracking time per frame and the
    published-pose latency (wall time from a frame's paced release to the publication of its state),
    windows mapped / offered / dropped. Tracking never waits for mapping: the mapper runs in the
    model worker and the queue drops the oldest pending window when it is busy.
  * `--onnx PATH`: the same with a real DA3 ONNX graph (e.g. random-weight DA3-Small at a reduced
    resolution, `davio export-da3 --random-init --size small --res 182x280`) on the CPU execution
    provider: throughput windows processed / offered (random weights are refused by the gates, which
    is what they should do; the cost is that of the graph).
  * `--memory-seconds S`: one long simulated run with mapping on (FastClock, rendered on the fly):
    resident-set size sampled every 10 s of sensor time.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from typing import Any

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, nonnegative, number, number_in

NAME = "mapping-cost"
HELP = "mapping's cost: tracking ms/frame and pose latency with mapping on/off, throughput, memory"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="euroc", help="motion preset of the simulated recording")
    p.add_argument("--seconds", type=number, default=30.0, help="length of the paced arms' recording")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--repeats", type=count(1, 100), default=1, help="off/on pairs (interleaved)")
    p.add_argument("--speed", type=number_in(0, 1000, low_open=True), default=1.0,
                   help="pacing factor of the arms (1 = real time)")
    p.add_argument("--no-arms", action="store_true", help="skip the paced on/off arms")
    p.add_argument("--onnx", metavar="PATH", default=None, help="also run a paced arm with this DA3 graph")
    p.add_argument("--threads", type=count(1, 256), default=2, help="ONNX Runtime intra-op threads (--onnx)")
    p.add_argument("--memory-seconds", type=nonnegative, default=0.0,
                   help="length of the memory run (0 = skip; the issue asks for 600)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE", default=None, help="also write the JSON to FILE")


def _rss_mb() -> float:
    """Current resident-set size of this process, MB (Linux /proc)."""
    import os

    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


class _MemoryDriver:
    """Replays pre-built events from memory (frames already rendered)."""

    def __init__(self, events: list, rig: Any) -> None:
        self._events, self.rig = events, rig

    def events(self):
        yield from self._events


def _pct(xs: list[float], q: float) -> float | None:
    return float(np.percentile(xs, q)) if xs else None


def _arm(events: list, rig: Any, model: Any, mapping: bool, speed: float) -> dict:
    """One paced replay; returns tracking ms/frame, pose latency and mapping counters."""
    from runtime.config import DavioConfig
    from runtime.pipeline import VioPipeline
    from runtime.scheduler import PacedClock, Scheduler

    cfg = DavioConfig()
    cfg = replace(cfg, mapping=replace(cfg.mapping, enabled=mapping))
    pipe = VioPipeline(rig, model, cfg)
    clock = PacedClock(speed)
    latency_ms: list[float] = []

    def on_output(states: list) -> None:
        now = time.monotonic()
        t0_ns, w0 = clock._t0
        for s in states:
            due = w0 + (int(s.t_cam_ns) - t0_ns) * 1e-9 / speed
            latency_ms.append(1e3 * (now - due))

    t0 = time.perf_counter()
    rep = Scheduler(clock, on_output=on_output).run(_MemoryDriver(events, rig).events(), pipe)
    wall = time.perf_counter() - t0
    pending = len(pipe.map_queue) if pipe.map_queue is not None else 0
    mp = pipe.report().get("mapping") or {}
    live = [x for x in latency_ms if x < 500.0]  # replayed start-up states (catch-up) are not live poses
    return {
        "mapping": mapping,
        "frames": rep.frames,
        "tracking_ms_median": _pct(rep.per_frame_ms, 50),
        "tracking_ms_p95": _pct(rep.per_frame_ms, 95),
        "pose_latency_ms_median": _pct(live, 50),
        "pose_latency_ms_p95": _pct(live, 95),
        "pose_latency_ms_max": max(live) if live else None,
        "published": len(pipe.published),
        "wall_s": wall,
        "windows_offered": mp.get("windows_offered", 0),
        "windows_processed": mp.get("windows_processed", 0),
        "windows_accepted": mp.get("windows_accepted", 0),
        "windows_dropped": mp.get("windows_dropped_queue", 0),
        "windows_pending_at_end": pending,
        "windows_rejected": mp.get("windows_rejected", {}),
        "model_busy_s": rep.model_busy_s,
        "stage_s": mp.get("stage_s", {}),
    }


def _memory_run(args: argparse.Namespace, progress: bool) -> dict:
    import sys

    from drivers.sim import SimConfig, SimRecording
    from models.emulated_da3 import EmulatedDA3
    from runtime.config import DavioConfig
    from tools.run_session import run_pipeline

    rec = SimRecording.from_preset(SimConfig(preset=args.preset, seconds=args.memory_seconds, seed=args.seed))
    cam = rec.rig.camera
    model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=args.seed)
    samples: list[tuple[float, float]] = []
    t_wall = time.perf_counter()

    class _Driver:
        rig = rec.rig

        def events(self):
            last = -1
            t0 = None
            for ev in rec.events():
                t0 = ev.t_ns if t0 is None else t0
                s = (ev.t_ns - t0) * 1e-9
                if int(s // 10) != last:
                    last = int(s // 10)
                    samples.append((s, _rss_mb()))
                    if progress:
                        print(f"  memory run: t = {s:5.0f} s  RSS {samples[-1][1]:7.1f} MB  "
                              f"({time.perf_counter() - t_wall:5.0f} s wall)", file=sys.stderr, flush=True)
                yield ev

    res = run_pipeline(_Driver(), model, DavioConfig(), show_progress=False)
    samples.append((args.memory_seconds, _rss_mb()))
    mp = res.pipeline.report().get("mapping") or {}
    s = np.array(samples)
    half = s[s[:, 0] >= 0.5 * args.memory_seconds]
    slope = float(np.polyfit(half[:, 0], half[:, 1], 1)[0]) * 60 if len(half) >= 2 else None
    return {"seconds": args.memory_seconds, "samples": samples, "rss_mb_start": float(s[0, 1]),
            "rss_mb_at_10pct": float(s[max(1, len(s) // 10), 1]), "rss_mb_at_50pct": float(s[len(s) // 2, 1]),
            "rss_mb_end": float(s[-1, 1]), "rss_mb_max": float(s[:, 1].max()),
            "rss_slope_second_half_mb_per_min": slope,
            "submaps": mp.get("windows_accepted"), "submaps_resident": mp.get("submaps_resident"),
            "submaps_evicted": mp.get("submaps_evicted"), "voxels": mp.get("voxels"),
            "graph_nodes_evicted": (mp.get("graph") or {}).get("evicted"),
            "revisit_views": (mp.get("graph") or {}).get("views"),
            "revisits_accepted": ((mp.get("graph") or {}).get("revisits") or {}).get("accepted"),
            "anchors_added": (mp.get("graph") or {}).get("anchors_added"),
            "wall_s": time.perf_counter() - t_wall}


def run(args: argparse.Namespace) -> int:
    import sys

    from drivers.sim import SimConfig, SimRecording
    from models.emulated_da3 import EmulatedDA3

    out: dict = {"benchmark": NAME, "preset": args.preset, "seconds": args.seconds, "speed": args.speed,
                 "arms": [], "onnx": None, "memory": None}
    progress = not args.json
    if not args.no_arms or args.onnx:
        rec = SimRecording.from_preset(SimConfig(preset=args.preset, seconds=args.seconds, seed=args.seed))
        t0 = time.perf_counter()
        events = list(rec.events())
        if progress:
            print(f"pre-rendered {len(rec)} frames in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        cam = rec.rig.camera
    if not args.no_arms:
        for r in range(args.repeats):
            for mapping in (False, True):
                model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base",
                                    seed=args.seed)
                row = _arm(events, rec.rig, model, mapping, args.speed)
                row["repeat"] = r
                out["arms"].append(row)
                if progress:
                    print(f"  arm mapping={'on ' if mapping else 'off'} repeat {r}: tracking "
                          f"{row['tracking_ms_median']:.1f} ms/frame, latency "
                          f"{row['pose_latency_ms_median']:.1f} ms", file=sys.stderr)
    if args.onnx:
        from models.da3 import OnnxDA3

        model = OnnxDA3(args.onnx, cam, providers=["CPUExecutionProvider"], threads=args.threads)
        warm = model.warm_up(5)
        row = _arm(events, rec.rig, model, True, args.speed)
        row.update(model=args.onnx, graph_hw=list(model.graph_hw), warm_up_s=warm)
        out["onnx"] = row
    if args.memory_seconds > 0:
        out["memory"] = _memory_run(args, progress)
    if args.out:
        from pathlib import Path

        Path(args.out).write_text(strict_dumps(out, indent=1))
    if args.json:
        print(strict_dumps(out))
        return 0
    _table(out)
    return 0


def _fmt(x: Any, spec: str = ".1f") -> str:
    return "-" if x is None else format(x, spec)


def _table(out: dict) -> None:
    rows = list(out["arms"]) + ([out["onnx"]] if out["onnx"] else [])
    if rows:
        print(f"mapping cost, preset {out['preset']}, {out['seconds']:.0f} s paced at {out['speed']}x "
              "(frames pre-rendered; 2-core figures depend on the machine's load)")
        print("| arm | tracking ms/frame median / p95 | pose latency ms median / p95 / max | windows "
              "processed / offered | dropped | accepted |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            name = ("DA3 ONNX " + "x".join(map(str, r["graph_hw"]))) if "graph_hw" in r else \
                ("emulated DA3, mapping " + ("on" if r["mapping"] else "off"))
            print(f"| {name} | {_fmt(r['tracking_ms_median'])} / {_fmt(r['tracking_ms_p95'])} | "
                  f"{_fmt(r['pose_latency_ms_median'])} / {_fmt(r['pose_latency_ms_p95'])} / "
                  f"{_fmt(r['pose_latency_ms_max'])} | {r['windows_processed']} / {r['windows_offered']} | "
                  f"{r['windows_dropped']} | {r['windows_accepted']} |")
    m = out["memory"]
    if m:
        slope = _fmt(m["rss_slope_second_half_mb_per_min"], ".2f")
        print(f"memory over {m['seconds']:.0f} s (mapping on, FastClock): RSS start "
              f"{m['rss_mb_start']:.0f} MB, 10 % {m['rss_mb_at_10pct']:.0f}, "
              f"50 % {m['rss_mb_at_50pct']:.0f}, "
              f"end {m['rss_mb_end']:.0f}, max {m['rss_mb_max']:.0f} MB; second-half slope {slope} MB/min; "
              f"{m['submaps']} submaps ({m['submaps_resident']} resident, {m['submaps_evicted']} evicted), "
              f"{m['voxels']} voxels; revisit views {m.get('revisit_views')}, revisits accepted "
              f"{m.get('revisits_accepted')}, anchors {m.get('anchors_added')}")
