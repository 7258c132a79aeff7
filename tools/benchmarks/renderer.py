"""`davio bench renderer`: simulator rendering speed (frames/s) at the EuRoC camera's 752x480."""

from __future__ import annotations

import argparse

from tools.cli_types import count

NAME = "renderer"
HELP = "simulator renderer speed: frames/s at 752x480 (numba warm-up excluded)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--frames", type=count(1, 10000), default=60, help="frames rendered after warm-up")
    p.add_argument("--threads", type=count(1, 256), default=None,
                   help="numba threads (default: numba's default)")
    p.add_argument("--seed", type=count(0), default=0, help="scene and motion seed")
    p.add_argument(
        "--threading-layer",
        default=None,
        choices=["workqueue", "omp", "tbb"],
        help="numba threading layer (default: workqueue like davio simulate, unless NUMBA_THREADING_LAYER)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")


def measure(frames: int = 60, seed: int = 0, threads: int | None = None, layer: str | None = None) -> dict:
    """Time ray casting alone and full frames (cast + exposure + noise + 8-bit) of an EuRoC-like recording."""
    import os
    import time

    import numba
    import numpy as np

    from drivers.sim.recording import SimConfig, SimRecording
    from drivers.sim.threads import prefer_workqueue_layer

    if layer is not None:  # must precede the first parallel kernel of the process
        numba.config.THREADING_LAYER = layer
    else:  # what `davio simulate` uses
        prefer_workqueue_layer()
    if threads is not None:
        numba.set_num_threads(threads)
    rec = SimRecording.from_preset(SimConfig(seconds=max(4.0, frames / 20.0 + 1.0), seed=seed))
    n = min(frames, len(rec))
    t0 = time.perf_counter()
    rec.render(0)  # numba compile / cache load
    warm_s = time.perf_counter() - t0
    caster = rec.renderer.caster
    R_WI, p_WI = rec.motion.pose(rec.frame_stamps_ns[:n])
    R_IC, p_IC = rec.rig.T_IC[:3, :3], rec.rig.T_IC[:3, 3]
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n):
        caster.cast(R_WI[k] @ R_IC, p_WI[k] + R_WI[k] @ p_IC)
    cast_s, cast_cpu_s = (time.perf_counter() - t0) / n, (time.process_time() - c0) / n
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n):
        rec.render(k)
    frame_s, frame_cpu_s = (time.perf_counter() - t0) / n, (time.process_time() - c0) / n
    cam = rec.rig.camera
    return {
        "width": cam.width,
        "height": cam.height,
        "frames": n,
        "numba_threads": numba.get_num_threads(),
        "threading_layer": numba.threading_layer(),
        "cpu_count": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "warmup_s": round(warm_s, 3),
        "cast_ms": round(cast_s * 1e3, 2),
        "frame_ms": round(frame_s * 1e3, 2),
        "cast_fps": round(1.0 / cast_s, 1),
        "cast_cpu_ms": round(cast_cpu_s * 1e3, 2),
        "frame_cpu_ms": round(frame_cpu_s * 1e3, 2),
        "frame_fps_if_threads_had_dedicated_cores": round(numba.get_num_threads() / frame_cpu_s, 1),
        "frame_fps": round(1.0 / frame_s, 1),
        "scene_boxes": rec.scene.n_boxes,
        "goal_fps": 20.0,
        "meets_goal": bool(1.0 / frame_s >= 20.0),
        "depth_valid_fraction": float(np.isfinite(rec.render(n - 1)[1].depth).mean()),
    }


def run(args: argparse.Namespace) -> int:
    from runtime.json_out import strict_dumps

    res = measure(args.frames, args.seed, args.threads, args.threading_layer)
    if args.json:
        print(strict_dumps(res))
        return 0
    from rich.console import Console
    from rich.table import Table

    t = Table(
        title=f"simulator renderer, {res['width']}x{res['height']}, {res['numba_threads']} numba threads "
        f"({res['threading_layer']}, load avg {res['load_average_1min']})"
    )
    t.add_column("stage")
    t.add_column("ms/frame", justify="right")
    t.add_column("frames/s", justify="right")
    t.add_column("CPU ms/frame (all threads)", justify="right")
    t.add_row("ray casting", f"{res['cast_ms']:.1f}", f"{res['cast_fps']:.1f}", f"{res['cast_cpu_ms']:.1f}")
    t.add_row(
        "full frame (cast + exposure + noise)",
        f"{res['frame_ms']:.1f}",
        f"{res['frame_fps']:.1f}",
        f"{res['frame_cpu_ms']:.1f}",
    )
    Console().print(t)
    print(
        f"goal >= 20 frames/s: {'met' if res['meets_goal'] else 'NOT met'} "
        f"(warm-up {res['warmup_s']} s excluded)"
    )
    return 0
