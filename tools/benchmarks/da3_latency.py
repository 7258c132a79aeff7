"""`davio bench da3-latency`: DA3 ONNX latency and peak memory for one N-view call.

Uses a DA3-shaped graph (by default DA3-Small at 378x504 with random weights: the latency of a
graph does not depend on its weights), exported once into a cache folder outside git with
`davio export-da3 --random-init` when absent. Times the full `OnnxDA3.predict` (undistortion,
resize, normalisation, inference, mapping back) for the unconditioned and the pose-conditioned
call, and the bare `session.run`. Peak memory is this process's maximum RSS (torch is never
imported here; the export runs in a child process).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count

NAME = "da3-latency"
HELP = "DA3 ONNX latency and peak memory (N views at HxW) on the selected execution provider"
CACHE = Path(os.environ.get("DAVIO_CACHE", Path.home() / ".cache" / "davio"))


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: kB


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--model",
        metavar="PATH",
        default=None,
        help="DA3 graph to time (default: CACHE/da3_SIZE_HxW_opOPSET[_fp16]_random.onnx, exported if absent)",
    )
    p.add_argument(
        "--size", default="small", choices=["tiny", "small", "base"], help="size of the default graph"
    )
    p.add_argument("--res", default="378x504", help="resolution HxW of the default graph")
    p.add_argument("--precision", default="fp32", choices=["fp32", "fp16"],
                   help="precision of the default graph (fp16: backbone in float16, `davio export-da3`)")
    p.add_argument("--views", type=count(1, 64), default=5, help="frames per call (N)")
    p.add_argument("--threads", type=count(1, 256), default=2, help="ONNX Runtime intra-op threads")
    p.add_argument("--repeats", type=count(1, 1000), default=5,
                   help="timed calls per mode (after one warm-up)")
    p.add_argument("--cpu", action="store_true", help="force the CPU execution provider")
    p.add_argument(
        "--cuda-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a CUDA execution-provider option (ONNX Runtime's name), repeatable; e.g. "
        "arena_extend_strategy=kSameAsRequested, gpu_mem_limit=4294967296",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _default_model(size: str, res: str, precision: str = "fp32") -> tuple[Path, float | None]:
    from runtime.errors import ModelError
    from tools.export.export_da3 import OPSET, ExportRequest, export_in_subprocess

    h, w = (int(v) for v in res.lower().split("x"))
    suffix = "" if precision == "fp32" else f"_{precision}"
    path = CACHE / f"da3_{size}_{h}x{w}_op{OPSET}{suffix}_random.onnx"
    if path.is_file():
        return path, None
    t0 = time.perf_counter()
    try:
        export_in_subprocess(ExportRequest(size=size, height=h, width=w, out=str(path), random_init=True,
                                           precision=precision))
    except ModelError as exc:
        raise SystemExit(
            f"da3-latency: cannot export the benchmark graph ({exc}); pass --model PATH"
        ) from exc
    return path, time.perf_counter() - t0


def _cuda_options(pairs: list[str]) -> dict[str, str]:
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise SystemExit(f"da3-latency: --cuda-option takes KEY=VALUE, got {pair!r}")
        out[key.strip()] = value.strip()
    return out


def run(args: argparse.Namespace) -> int:
    from calib import Pinhole
    from models.da3 import OnnxDA3
    from runtime.events import Frame

    if args.repeats < 1 or not 2 <= args.views <= 8:
        raise SystemExit("da3-latency: --repeats must be >= 1 and --views in 2..8")
    cuda_options = _cuda_options(args.cuda_option)   # checked before any export
    export_s = None
    if args.model:
        path = Path(args.model)
    else:
        path, export_s = _default_model(args.size, args.res, args.precision)
    rss0 = _rss_mb()
    cam = Pinhole(640, 480, 458.0, 457.0, 319.5, 239.5)
    t0 = time.perf_counter()
    model = OnnxDA3(path, cam, providers=["CPUExecutionProvider"] if args.cpu else None, threads=args.threads,
                    cuda_options=cuda_options)
    load_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    n = args.views
    frames = [Frame(i * 50_000_000, rng.integers(0, 255, (480, 640), dtype=np.uint8)) for i in range(n)]
    T_CW = np.tile(np.eye(4), (n, 1, 1))
    T_CW[:, 0, 3] = -0.1 * np.arange(n)
    K = np.tile(cam.K, (n, 1, 1))
    timings: dict[str, list[float]] = {"uncond_predict": [], "cond_predict": [], "session_run": [],
                                       "prepare_images": []}
    t = time.perf_counter()
    model.predict(frames)  # the first call: one-off session costs (what `OnnxDA3.warm_up` absorbs at load)
    first_call_s = time.perf_counter() - t
    for _ in range(args.repeats):
        t = time.perf_counter()
        model.predict(frames)
        timings["uncond_predict"].append(time.perf_counter() - t)
        t = time.perf_counter()
        model.predict(frames, K, T_CW)
        timings["cond_predict"].append(time.perf_counter() - t)
    for _ in range(args.repeats):
        t = time.perf_counter()
        images = model._images(frames)  # undistortion, resize, normalisation: always on the CPU
        timings["prepare_images"].append(time.perf_counter() - t)
    eye3, eye4 = (
        np.tile(np.eye(3, dtype=np.float32), (1, n, 1, 1)),
        np.tile(np.eye(4, dtype=np.float32), (1, n, 1, 1)),
    )
    for _ in range(args.repeats):
        t = time.perf_counter()
        model.session.run(
            None, {"images": images, "intrinsics": eye3, "extrinsics": eye4, "use_pose": np.array([False])}
        )
        timings["session_run"].append(time.perf_counter() - t)
    card_path = path.with_suffix(".json")
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    out = {
        "benchmark": NAME,
        "model": str(path),
        "size": card.get("size"),
        "precision": model.precision,
        "graph_hw": list(model.graph_hw),
        "views": n,
        "threads": args.threads,
        "providers": model.session_info["providers"],
        "provider_reason": model.session_info["reason"],
        "cuda_options": model.session_info.get("cuda_options"),
        "model_mb": round(path.stat().st_size / 1e6, 1),
        "load_s": round(load_s, 2),
        "first_call_s": round(first_call_s, 3),
        "export_s": None if export_s is None else round(export_s, 1),
        "latency_s": {
            k: {"median": float(np.median(v)), "min": float(np.min(v))} for k, v in timings.items()
        },
        "peak_rss_mb": round(_rss_mb(), 0),
        "rss_before_load_mb": round(rss0, 0),
        "cpu_count": os.cpu_count(),
    }
    if args.json:
        print(strict_dumps(out))
        return 0
    print(
        f"DA3 {out['size'] or '?'} {out['precision']} {model.graph_hw[0]}x{model.graph_hw[1]}, N={n}, "
        f"{args.threads} threads, "
        f"{out['providers'][0]} ({out['model_mb']} MB graph, load {out['load_s']} s, "
        f"first call {out['first_call_s']:.3f} s)"
    )
    print(f"{'call':<16}{'median s':>10}{'min s':>8}")
    for k, v in out["latency_s"].items():
        print(f"{k:<16}{v['median']:>10.3f}{v['min']:>8.3f}")
    print(
        f"peak RSS {out['peak_rss_mb']:.0f} MB (before loading the graph {out['rss_before_load_mb']:.0f} MB)"
    )
    return 0
