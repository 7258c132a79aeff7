"""`--gpu-mem-limit`: the CUDA options it sets, and its refusals before any work."""

from __future__ import annotations

import argparse

import pytest

from runtime.errors import ConfigError
from tools.cli import main
from tools.model_open import MIN_GPU_MEM_LIMIT_MB, check_gpu_memory_args, cuda_options


def _args(**kw) -> argparse.Namespace:
    return argparse.Namespace(**{"model": "m.onnx", "gpu_mem_limit": None, **kw})


def test_the_cap_becomes_onnx_runtime_bytes_and_growth_by_request():
    assert cuda_options(_args()) == {}
    assert cuda_options(_args(gpu_mem_limit=4096.0)) == {  # the options the cap was measured with
        "gpu_mem_limit": "4096000000", "arena_extend_strategy": "kSameAsRequested",
        "cudnn_conv_use_max_workspace": "0", "cudnn_conv_algo_search": "HEURISTIC"}
    assert cuda_options(_args(gpu_mem_limit=float(MIN_GPU_MEM_LIMIT_MB)))["gpu_mem_limit"] == "256000000"


@pytest.mark.parametrize("mb", [float("nan"), float("inf"), -1.0, MIN_GPU_MEM_LIMIT_MB - 0.5])
def test_a_cap_that_cannot_hold_a_graph_is_refused(mb):
    with pytest.raises(ConfigError, match="give megabytes, from 256 to 1e\\+07"):
        check_gpu_memory_args(_args(gpu_mem_limit=mb))


def test_a_cap_without_a_model_is_refused(tmp_path, capsys):
    with pytest.raises(ConfigError, match="needs --model"):
        check_gpu_memory_args(_args(model=None, gpu_mem_limit=1024.0))
    # davio run refuses it before reading the recording (the folder does not exist)
    assert main(["run", str(tmp_path / "absent"), "--native-only", "--gpu-mem-limit", "1024",
                 "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "--gpu-mem-limit caps the DA3 graph's GPU memory" in err and "not found" not in err
    assert not (tmp_path / "out").exists()


def test_a_measured_latency_needs_a_model(tmp_path, capsys):
    assert main(["run", str(tmp_path / "absent"), "--native-only", "--model-latency", "measured",
                 "--out", str(tmp_path / "out")]) == 1
    assert "--model-latency measured times the --model graph: it needs --model" in capsys.readouterr().err
    with pytest.raises(SystemExit):   # neither seconds nor 'measured': argparse's own error
        main(["run", str(tmp_path), "--model-latency", "fast", "--out", str(tmp_path / "out")])
    assert "seconds or 'measured': 'fast' is not a number" in capsys.readouterr().err
