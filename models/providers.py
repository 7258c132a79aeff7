"""ONNX Runtime session creation: execution-provider choice and explicit thread settings.

The CUDA execution provider is asked for when the installed ONNX Runtime offers it (the
`onnxruntime-gpu` wheel) and a GPU is visible; otherwise the CPU provider is used and the reason is
logged and reported by `davio info`. Threads are always set explicitly and intra-op spinning is
off: on small CPUs shared with the filter, spinning threads double the latency (notes/matcher.md).
"""

from __future__ import annotations

import contextlib
import functools
import io
import logging
import os
import re
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from models.onnx_file import ContractCheck, check_model_file, require_file
from runtime.errors import ModelError

if TYPE_CHECKING:
    import onnxruntime as ort

log = logging.getLogger(__name__)

CUDA = "CUDAExecutionProvider"
CPU = "CPUExecutionProvider"

#: Environment variable that forces the CPU provider (e.g. to compare timings).
FORCE_CPU_ENV = "DAVIO_FORCE_CPU"


def _available_providers() -> list[str]:
    import onnxruntime as ort

    return list(ort.get_available_providers())


def _installed_onnxruntime_wheels() -> set[str]:
    """Which ONNX Runtime distributions pip installed (they share the import package `onnxruntime`)."""
    from importlib.metadata import PackageNotFoundError, version

    found = set()
    for name in ("onnxruntime", "onnxruntime-gpu"):
        try:
            version(name)
        except PackageNotFoundError:
            continue
        found.add(name)
    return found


#: how to get the CUDA provider when the CPU wheel is (also) installed
GPU_REINSTALL = ("pip uninstall -y onnxruntime onnxruntime-gpu && "
                 "pip install 'onnxruntime-gpu[cuda,cudnn]>=1.27'")


def _cuda_device_visible() -> tuple[bool, str]:
    """Whether a CUDA device looks usable, with the reason when it does not."""
    if os.environ.get("CUDA_VISIBLE_DEVICES", None) in ("", "-1"):
        return False, "CUDA_VISIBLE_DEVICES hides every GPU"
    if sys.platform == "win32":
        return True, "Windows (no device-node check)"
    # desktop/server GPUs, WSL, Jetson (integrated GPU)
    if any(Path(p).exists() for p in ("/dev/nvidia0", "/dev/nvidiactl", "/dev/dxg", "/dev/nvhost-ctrl-gpu")):
        return True, "GPU device node present"
    if Path("/proc/driver/nvidia/version").exists():
        return True, "NVIDIA driver loaded"
    return False, "no NVIDIA GPU device found"


def choose_providers(requested: Sequence[str] | None = None) -> tuple[list[str], str]:
    """Pick the execution providers for a session.

    Args:
        requested: explicit provider names (e.g. ["CPUExecutionProvider"]); None = automatic.

    Returns:
        (providers in priority order, reason for the choice).

    Raises:
        ModelError: a requested provider is not offered by the installed ONNX Runtime.
    """
    available = _available_providers()
    if requested:
        missing = [p for p in requested if p not in available]
        if missing:
            raise ModelError(
                f"execution provider(s) {missing} not available; ONNX Runtime offers {available}"
            )
        return list(requested), "requested explicitly"
    if os.environ.get(FORCE_CPU_ENV, "") not in ("", "0"):
        return [CPU], f"{FORCE_CPU_ENV} is set"
    if CUDA not in available:
        if "onnxruntime-gpu" in _installed_onnxruntime_wheels():   # the CPU wheel's files won
            return [CPU], ("onnxruntime-gpu is installed but the CPU package onnxruntime shares its files "
                           f"and hides the CUDA provider: {GPU_REINSTALL}")
        return [CPU], "CUDAExecutionProvider not offered by this ONNX Runtime (install onnxruntime-gpu)"
    visible, why = _cuda_device_visible()
    if not visible:
        return [CPU], f"onnxruntime-gpu installed but {why}"
    return [CUDA, CPU], f"onnxruntime-gpu installed and {why}"


def describe_providers() -> dict:
    """What `davio info` shows: the provider DA3 will use, why, and what ONNX Runtime offers."""
    try:
        providers, reason = choose_providers()
        available = _available_providers()
    except Exception as exc:  # a broken install is reported, not raised
        return {"selected": None, "reason": f"{type(exc).__name__}: {exc}", "available": []}
    out = {"selected": providers[0], "reason": reason, "available": available}
    if _installed_onnxruntime_wheels() == {"onnxruntime", "onnxruntime-gpu"}:
        out["warning"] = ("both onnxruntime and onnxruntime-gpu are installed; they share the import package "
                          f"and either may be the one that loads: {GPU_REINSTALL}")
    return out


def preload_cuda_libraries(ort) -> str:
    """Load CUDA and cuDNN from pip's `nvidia-*` packages before a CUDA session (`onnxruntime.preload_dlls`).

    onnxruntime-gpu does not find the CUDA libraries that `pip install onnxruntime-gpu[cuda,cudnn]`
    puts in site-packages by itself (only through LD_LIBRARY_PATH, a system CUDA install, or an
    earlier `import torch`, which the runtime never does), and the session then falls back to the
    CPU. Missing libraries are not an error here: the fallback is detected and reported after the
    session is made. Returns what happened, for the log; what ONNX Runtime prints goes to the log.
    """
    preload = getattr(ort, "preload_dlls", None)
    if preload is None:  # onnxruntime < 1.21
        return "onnxruntime has no preload_dlls"
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            preload()
    except Exception as exc:  # a library that fails to load: the session's own fallback says the rest
        log.warning("loading the CUDA libraries failed: %s: %s", type(exc).__name__, exc)
        return f"preload failed ({type(exc).__name__}: {exc})"
    for line in printed.getvalue().splitlines():
        if line.strip():
            log.info("onnxruntime.preload_dlls: %s", line.strip())
    return "preloaded"


def default_threads() -> int:
    """Intra-op threads when none are configured: all cores up to 4, leaving one on >2-core CPUs."""
    n = os.cpu_count() or 1
    return max(1, min(4, n - 1 if n > 2 else n))


@functools.cache
def quiet_run_options() -> ort.RunOptions:
    """ONNX Runtime RunOptions under which a run logs nothing below fatal on stderr: its warnings and its
    error on a failing run are not said (the caller raises the failure as a ModelError carrying the same
    text; it was said twice, the log's copy in colour codes). One instance, made on first use and shared
    by every run (read-only: nobody sets its `terminate` flag)."""
    import onnxruntime as ort

    options = ort.RunOptions()
    options.log_severity_level = 4     # fatal only
    return options


def create_session(
    path: str | Path,
    providers: Sequence[str] | None = None,
    threads: int | None = None,
    contract: ContractCheck | None = None,
    cuda_options: Mapping[str, str] | None = None,
):
    """Create an ONNX Runtime InferenceSession with explicit providers and thread settings.

    The file is checked first (`models.onnx_file.check_model_file`): ONNX Runtime never parses a
    file that is not an ONNX model, reads tensor data from outside the model's folder, or (with
    `contract`) declares inputs and outputs that break the contract.

    Args:
        path: the .onnx file.
        providers: explicit execution providers, or None for the automatic choice.
        threads: intra-op threads (None = `default_threads()`); inter-op is 1 (sequential).
        contract: signature check of the expected contract (e.g. `check_da3_signature`), or None.
        cuda_options: CUDA execution-provider options (ONNX Runtime's names, values as strings, e.g.
            {"gpu_mem_limit": "2147483648"}); ONNX Runtime's defaults otherwise (measured best for the
            opset-23 DA3 graphs, BENCHMARKS.md "DA3 on a GPU"); unused on the CPU.

    Returns:
        (session, info dict with 'providers' actually used, 'reason', 'threads', and 'cuda_options':
        the CUDA provider's effective options as ONNX Runtime reports them, when it runs).

    Raises:
        ModelError: the file is missing, refused by the checks, or ONNX Runtime cannot load it.
    """
    import onnxruntime as ort

    path = Path(path)
    require_file(path)
    if threads is not None and threads < 1:
        raise ModelError(f"intra-op threads must be >= 1, got {threads}")
    check_model_file(path, contract)
    chosen, reason = choose_providers(providers)
    if chosen[0] == CUDA:
        preload_cuda_libraries(ort)
    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads or default_threads())
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.add_session_config_entry("session.inter_op.allow_spinning", "0")
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    with_options: list = list(chosen)
    if chosen[0] == CUDA:
        with_options[0] = (CUDA, {str(k): str(v) for k, v in (cuda_options or {}).items()})
    try:
        sess = ort.InferenceSession(str(path), sess_options=so, providers=with_options)
    except Exception as exc:
        raise ModelError(load_failure(path, exc, ort.__version__)) from exc
    used = list(sess.get_providers())
    if chosen[0] == CUDA and used[0] != CUDA:
        reason = (
            f"CUDA provider requested but the session fell back to {used[0]} (CUDA/cuDNN libraries missing?)"
        )
        log.warning("%s: %s", path.name, reason)
    elif used[0] == CPU and providers is None:
        log.info("%s runs on the CPU: %s", path.name, reason)
    info = {"providers": used, "reason": reason, "threads": so.intra_op_num_threads}
    if used[0] == CUDA:
        info["cuda_options"] = dict(sess.get_provider_options().get(CUDA, {}))
    return sess, info


def load_failure(path: Path, exc: Exception, ort_version: str) -> str:
    """The message for a graph ONNX Runtime cannot load: its C++ text on one line, and for an opset or IR
    version beyond this ONNX Runtime, what to do."""
    text = " ".join(str(exc).split())
    hint = ""
    if re.search(r"till opset|max supported IR version|opset \d+ is under development", text, re.IGNORECASE):
        hint = (f"; the graph needs a newer ONNX Runtime than the installed {ort_version}: upgrade "
                "onnxruntime, or export it for an older opset (`davio export-da3 --opset 18`)")
    return f"{path}: ONNX Runtime cannot load the model ({type(exc).__name__}: {text}){hint}"
