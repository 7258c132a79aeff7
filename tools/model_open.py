"""Opening the DA3 graph for `davio run`, `live` and `calibrate`: the GPU memory cap, the warm-up, and
the latency a replay simulates when asked to measure it (`--model-latency measured`).

ONNX Runtime's CUDA arena keeps what it once allocated and grows by powers of two by default: an opset-18
DA3-Base graph on 5 views held 10.7 GiB of an H100, and ran as fast under a 4 GiB cap with the options
below (BENCHMARKS.md, "DA3 on a GPU"). `--gpu-mem-limit MB` sets that cap, for a small GPU or one
shared with other programs. An opset-23 graph (the export's default) needs no cap at 5 views (3.7 GiB);
under these options it ran 6 % slower.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from runtime.errors import ConfigError
from tools.cli_types import number

#: the --model-latency value that times one call of the graph instead of a number of seconds
MEASURED = "measured"
#: smallest cap accepted: the CUDA context alone takes about 500 MB, the smallest DA3 graph more
MAX_MODEL_LATENCY_S = 3600.0
"""Largest --model-latency (sensor seconds) a replay takes: beyond it no window would ever be mapped."""
MAX_GPU_MEM_LIMIT_MB = 1e7
"""Largest --gpu-mem-limit (10 TB, beyond any GPU)."""
MIN_GPU_MEM_LIMIT_MB = 256
#: set with the cap, as measured with it: the arena grows by what is asked, cuDNN picks its algorithms by
#: heuristics with a small workspace (its exhaustive search can ask for gigabytes)
CAP_OPTIONS = {"arena_extend_strategy": "kSameAsRequested", "cudnn_conv_use_max_workspace": "0",
               "cudnn_conv_algo_search": "HEURISTIC"}


def add_gpu_memory_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--gpu-mem-limit", type=number, default=None, metavar="MB",
        help="cap ONNX Runtime's CUDA memory arena at MB megabytes, growing it by request and keeping "
        "cuDNN's workspace small (default: no cap; an opset-18 DA3-Base graph on 5 views ran within 4295 at "
        "full speed). No effect on the CPU",
    )


def cuda_options(args: argparse.Namespace) -> dict[str, str]:
    """CUDA execution-provider options of the command line (empty without --gpu-mem-limit).

    Raises:
        ConfigError: a cap that is not a finite number of at least MIN_GPU_MEM_LIMIT_MB.
    """
    mb = getattr(args, "gpu_mem_limit", None)
    if mb is None:
        return {}
    if not (math.isfinite(mb) and MIN_GPU_MEM_LIMIT_MB <= mb <= MAX_GPU_MEM_LIMIT_MB):
        raise ConfigError(f"--gpu-mem-limit {mb:g}: give megabytes, from {MIN_GPU_MEM_LIMIT_MB} to "
                          f"{MAX_GPU_MEM_LIMIT_MB:g}")
    return {**CAP_OPTIONS, "gpu_mem_limit": str(int(mb * 1e6))}


def check_gpu_memory_args(args: argparse.Namespace) -> None:
    """ConfigError, before any work, for a --gpu-mem-limit that is invalid or has no --model to cap."""
    cuda_options(args)
    if getattr(args, "gpu_mem_limit", None) is not None and not getattr(args, "model", None):
        raise ConfigError("--gpu-mem-limit caps the DA3 graph's GPU memory: it needs --model ONNX")


def open_da3(args: argparse.Namespace, camera: Any, views: int) -> tuple[Any, str]:
    """(model, description): `args.model` loaded and warmed up on `views` frames.

    The warm-up pays the session's one-off costs (arena, cuDNN search) before the run and shows at
    once that the graph runs within the memory cap.
    """
    from models.da3 import OnnxDA3

    model = OnnxDA3(args.model, camera, cuda_options=cuda_options(args))
    warm_s = model.warm_up(views)
    from models.providers import CUDA

    provider = model.session_info["providers"][0]
    cap = getattr(args, "gpu_mem_limit", None)
    capped = f", arena capped at {cap:g} MB" if cap is not None and provider == CUDA else ""
    return model, f"DA3 ONNX {args.model} on {provider}{capped} (warm-up call {warm_s:.2f} s)"


def latency_arg(text: str) -> float | str:
    """argparse type of --model-latency: seconds, or "measured" (one timed call of the graph)."""
    if text.strip().lower() == MEASURED:
        return MEASURED
    try:
        return number(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"seconds or '{MEASURED}': {exc}") from None


def measured_latency(model: Any, views: int) -> float:
    """Seconds of one call of the warmed-up graph on `views` frames (image preparation included): the
    latency a replay simulates with --model-latency measured."""
    return float(model.warm_up(views))
