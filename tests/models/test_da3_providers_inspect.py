"""Execution-provider choice (CUDA path by monkeypatching), session settings, `inspect_model`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from da3_contract_graph import build_da3_contract_graph
from onnx import TensorProto, helper

from models import providers
from models.inspect_model import inspect_model
from runtime.errors import ModelError


@pytest.fixture
def graph(tmp_path):
    return build_da3_contract_graph(tmp_path / "da3_contract_28x42.onnx", 28, 42)


def fake_gpu(monkeypatch, offered: bool, visible: bool):
    base = ["CPUExecutionProvider"]
    monkeypatch.setattr(
        providers, "_available_providers", lambda: (["CUDAExecutionProvider"] if offered else []) + base
    )
    monkeypatch.setattr(
        providers,
        "_cuda_device_visible",
        lambda: (visible, "GPU device node present" if visible else "no NVIDIA GPU device found"),
    )
    monkeypatch.delenv(providers.FORCE_CPU_ENV, raising=False)


def test_cuda_is_chosen_when_offered_and_visible(monkeypatch):
    fake_gpu(monkeypatch, True, True)
    chosen, reason = providers.choose_providers()
    assert chosen == ["CUDAExecutionProvider", "CPUExecutionProvider"]
    d = providers.describe_providers()
    assert d["selected"] == "CUDAExecutionProvider" and "CUDAExecutionProvider" in d["available"]


@pytest.mark.parametrize(
    "offered,visible,words", [(False, False, "onnxruntime-gpu"), (True, False, "no NVIDIA GPU")]
)
def test_cpu_fallback_reason(monkeypatch, offered, visible, words):
    fake_gpu(monkeypatch, offered, visible)
    chosen, reason = providers.choose_providers()
    assert chosen == ["CPUExecutionProvider"] and words in reason
    d = providers.describe_providers()
    assert set(d) == {"selected", "reason", "available"}
    assert d["selected"] == "CPUExecutionProvider" and words in d["reason"]


def test_force_cpu_env(monkeypatch):
    fake_gpu(monkeypatch, True, True)
    monkeypatch.setenv(providers.FORCE_CPU_ENV, "1")
    assert providers.choose_providers() == (["CPUExecutionProvider"], f"{providers.FORCE_CPU_ENV} is set")


@pytest.mark.filterwarnings("ignore:Specified provider 'CUDAExecutionProvider'")
def test_session_reports_fallback_when_cuda_cannot_start(monkeypatch, graph):
    # the CPU wheel cannot start CUDA: the session falls back and says so
    fake_gpu(monkeypatch, True, True)
    sess, info = providers.create_session(graph, threads=1)
    assert info["providers"][0] == "CPUExecutionProvider"
    assert "fell back" in info["reason"]


def test_session_threads_and_spinning(graph):
    sess, info = providers.create_session(graph, providers=["CPUExecutionProvider"], threads=2)
    assert info["threads"] == 2
    assert sess.get_session_options().get_session_config_entry("session.intra_op.allow_spinning") == "0"
    with pytest.raises(ModelError, match="threads"):
        providers.create_session(graph, threads=0)
    with pytest.raises(ModelError, match="not available"):
        providers.create_session(graph, providers=["NoSuchExecutionProvider"])


def test_inspect_model_reports_contract_and_card(graph):
    card = {"contract": "davio.da3", "contract_version": 1, "checkpoint": "random-init"}
    graph.with_suffix(".json").write_text(json.dumps(card))
    info = inspect_model(graph)
    assert info["contract"] == "davio.da3" and info["resolution"] == [28, 42]
    assert [i["name"] for i in info["inputs"]] == ["images", "intrinsics", "extrinsics", "use_pose"]
    assert info["outputs"][0]["shape"] == [1, None, 28, 42]
    assert info["model_card"] == card
    assert info["opset"]["ai.onnx"] == 18


def test_inspect_model_errors(tmp_path, graph):
    with pytest.raises(ModelError, match="not found"):
        inspect_model(tmp_path / "absent.onnx")
    (tmp_path / "folder.onnx").mkdir()                     # a folder named like a model: said so
    with pytest.raises(ModelError, match="folder.onnx is a folder, not an ONNX model file"):
        inspect_model(tmp_path / "folder.onnx")
    with pytest.raises(ModelError, match="is a folder, not an ONNX model file"):
        providers.create_session(tmp_path / "folder.onnx")
    (tmp_path / "link.onnx").symlink_to("absent.onnx")     # not "not found": the link is there
    with pytest.raises(ModelError, match="link.onnx is a broken symbolic link"):
        inspect_model(tmp_path / "link.onnx")
    with pytest.raises(ModelError, match="/dev/null is not a regular file"):
        inspect_model(Path("/dev/null"))
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(np.random.default_rng(1).integers(0, 255, 999, dtype=np.uint8).tobytes())
    with pytest.raises(ModelError, match="not a readable ONNX model"):
        inspect_model(bad)
    for variant in ("missing_output", "wrong_dtype", "dynamic_hw", "wrong_rank"):
        with pytest.raises(ModelError):
            inspect_model(build_da3_contract_graph(tmp_path / f"{variant}.onnx", variant=variant))
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3])
    other = helper.make_model(
        helper.make_graph([helper.make_node("Relu", ["x"], ["y"])], "g", [x], [y]),
        opset_imports=[helper.make_opsetid("", 18)],
    )
    onnx.save(other, str(tmp_path / "other.onnx"))
    with pytest.raises(ModelError, match="neither"):
        inspect_model(tmp_path / "other.onnx")
    graph.with_suffix(".json").write_text("{not json")
    with pytest.raises(ModelError, match="model card"):
        inspect_model(graph)


def test_a_graph_for_a_fixed_other_view_count_is_noted_where_it_is_inspected(tmp_path, capsys, monkeypatch):
    """`davio info --model` said nothing of a graph exported for 4 views, which `davio run` then refused with
    "got 5" and no way out; the table also read the shapes' brackets as markup."""
    from models.da3 import OnnxDA3
    from runtime.errors import DataError
    from tests.models.test_da3_runtime import CAM
    from tools.cli import main

    path = build_da3_contract_graph(tmp_path / "[v2]n4.onnx", 28, 42, variant="fixed_n")
    note = inspect_model(path)["note"]
    assert note.startswith("exported for exactly 4 views: DAVIO calls DA3 on 5-image windows")
    assert "re-export it with a dynamic view count" in note
    assert "note" not in inspect_model(build_da3_contract_graph(tmp_path / "dyn.onnx", 28, 42))
    with pytest.raises(DataError, match="exported for exactly 4 views, got 5: re-export it with a dynamic"):
        OnnxDA3(path, CAM, threads=1).warm_up(5)
    monkeypatch.setenv("COLUMNS", "1000")                  # one line per row: the table does not wrap
    assert main(["info", "--model", str(path)]) == 0
    out = capsys.readouterr().out
    assert "[v2]n4.onnx" in out and '"shape": [1, 4, 3, 28, 42]' in out


def test_a_graph_for_a_newer_onnx_runtime_is_said_on_one_line_with_what_to_do():
    newer = RuntimeError("[ONNXRuntimeError] : 1 : FAIL : Load model from x.onnx failed:/src/model_load_utils"
                         ".h:46 void f(...) ONNX Runtime only *guarantees* support for models stamped with "
                         "official released onnx opset versions. Opset 99 is under development\nCurrent "
                         "official support for domain ai.onnx is till opset 28.\n")
    text = providers.load_failure(Path("x.onnx"), newer, "1.32.0")
    assert "\n" not in text
    assert text.endswith("till opset 28.); the graph needs a newer ONNX Runtime than the installed 1.32.0: "
                         "upgrade onnxruntime, or export it for an older opset "
                         "(`davio export-da3 --opset 18`)")
    other = providers.load_failure(Path("x.onnx"), RuntimeError("Could not find an implementation for Foo"),
                                   "1.32.0")
    assert other == "x.onnx: ONNX Runtime cannot load the model (RuntimeError: Could not find an " \
                    "implementation for Foo)"


@pytest.mark.filterwarnings("ignore:Specified provider 'CUDAExecutionProvider'")
def test_cuda_session_preloads_pip_cuda_libraries_first(monkeypatch, graph, caplog):
    # onnxruntime-gpu finds pip's nvidia-* libraries only after preload_dlls: called for a CUDA session
    import onnxruntime as ort

    calls = []

    def preload():
        calls.append("cuda")
        print("WARNING: cuDNN 9 not found")  # what ORT prints goes to the log, never to stdout

    monkeypatch.setattr(ort, "preload_dlls", preload, raising=False)
    fake_gpu(monkeypatch, True, True)
    with caplog.at_level("INFO", logger="models.providers"):
        providers.create_session(graph, threads=1)
    assert calls == ["cuda"]
    assert "cuDNN 9 not found" in caplog.text
    providers.create_session(graph, providers=["CPUExecutionProvider"], threads=1)
    fake_gpu(monkeypatch, False, False)
    providers.create_session(graph, threads=1)
    assert calls == ["cuda"]  # never for a CPU session


@pytest.mark.filterwarnings("ignore:Specified provider 'CUDAExecutionProvider'")
def test_failed_preload_is_logged_and_the_session_still_made(monkeypatch, graph, caplog):
    # a preload that raises is logged, never raised; the session is made and its provider reported (the CPU
    # here: this machine's wheel has no CUDA provider, as a machine whose CUDA libraries are missing)
    import onnxruntime as ort

    def preload():
        raise OSError("libcudnn.so.9: cannot open shared object file")

    monkeypatch.setattr(ort, "preload_dlls", preload, raising=False)
    fake_gpu(monkeypatch, True, True)
    with caplog.at_level("WARNING", logger="models.providers"):
        sess, info = providers.create_session(graph, threads=1)
    assert "libcudnn.so.9" in caplog.text
    assert info["providers"][0] == "CPUExecutionProvider" and "fell back" in info["reason"]
    monkeypatch.delattr(ort, "preload_dlls")  # onnxruntime < 1.21
    assert providers.preload_cuda_libraries(ort) == "onnxruntime has no preload_dlls"


@pytest.mark.filterwarnings("ignore:Specified provider 'CUDAExecutionProvider'")
def test_cuda_options_reach_onnxruntime_as_strings(monkeypatch, graph):
    import onnxruntime as ort

    seen = []
    real = ort.InferenceSession

    def spy(path, sess_options=None, providers=None):
        seen.append(providers)
        return real(path, sess_options=sess_options, providers=["CPUExecutionProvider"])

    monkeypatch.setattr(ort, "InferenceSession", spy)
    monkeypatch.setattr(ort, "preload_dlls", lambda: None, raising=False)
    fake_gpu(monkeypatch, True, True)
    providers.create_session(graph, threads=1)
    assert seen[-1] == [("CUDAExecutionProvider", {}), "CPUExecutionProvider"]  # ONNX Runtime's defaults
    providers.create_session(graph, threads=1, cuda_options={"use_tf32": 0, "gpu_mem_limit": 2 << 30})
    assert seen[-1] == [("CUDAExecutionProvider", {"use_tf32": "0", "gpu_mem_limit": str(2 << 30)}),
                        "CPUExecutionProvider"]
    providers.create_session(graph, providers=["CPUExecutionProvider"], threads=1, cuda_options={"a": 0})
    assert seen[-1] == ["CPUExecutionProvider"]


def test_an_opset_18_attention_graph_gets_the_memory_note(tmp_path, graph):
    assert "note" not in inspect_model(graph)           # no attention at all: nothing to say
    model = onnx.load(graph)
    model.graph.node.append(helper.make_node("Softmax", ["images"], ["attn_probs"], axis=-1))
    spelled_out = tmp_path / "da3_op18.onnx"
    onnx.save(model, spelled_out)
    assert "an opset-18 export" in inspect_model(spelled_out)["note"]


def test_the_cpu_wheel_hiding_onnxruntime_gpu_is_named_with_the_fix(monkeypatch):
    # pip puts both wheels' files in one `onnxruntime` folder: whichever was written last loads
    fake_gpu(monkeypatch, False, True)
    both = {"onnxruntime", "onnxruntime-gpu"}
    monkeypatch.setattr(providers, "_installed_onnxruntime_wheels", lambda: both)
    chosen, reason = providers.choose_providers()
    assert chosen == ["CPUExecutionProvider"] and "hides the CUDA provider" in reason
    assert providers.GPU_REINSTALL in reason
    d = providers.describe_providers()
    assert "both onnxruntime and onnxruntime-gpu are installed" in d["warning"]
    monkeypatch.setattr(providers, "_installed_onnxruntime_wheels", lambda: {"onnxruntime"})
    assert "install onnxruntime-gpu" in providers.choose_providers()[1]
    assert "warning" not in providers.describe_providers()
    monkeypatch.undo()
    assert "onnxruntime" in providers._installed_onnxruntime_wheels()   # this machine's CPU wheel


def test_a_failing_run_is_said_once_through_the_exception(tmp_path, capfd):
    """ONNX Runtime logs a failing run on stderr (in colour) besides raising it; under quiet_run_options only
    the exception, which the models turn into a ModelError, carries the message."""
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, None)
    shape = helper.make_tensor_value_info("s", TensorProto.INT64, [2])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, None)
    graph = helper.make_graph([helper.make_node("Reshape", ["x", "s"], ["y"])], "g", [x, shape], [y])
    path = tmp_path / "reshape.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)
    sess, _ = providers.create_session(path, providers=[providers.CPU], threads=1)
    feeds = {"x": np.ones(6, np.float32), "s": np.array([4, 4])}
    capfd.readouterr()
    with pytest.raises(Exception, match="cannot be reshaped"):
        sess.run(None, feeds)
    assert "cannot be reshaped" in capfd.readouterr().err          # said twice without the options
    with pytest.raises(Exception, match="cannot be reshaped"):
        sess.run(None, feeds, providers.quiet_run_options())
    assert capfd.readouterr().err == ""


def test_a_view_count_that_disagrees_between_tensors_names_both():
    """A graph whose session reported depth with 4 views and conf dynamic was told "output 'conf' dim 1 (N)
    is None but another tensor has 4": the tensor that disagreed was not the one named, and None is no
    size."""
    from models.da3.contract import INPUTS, OUTPUTS, check_da3_signature

    def concrete(sig, n):
        dims = {"N": n, "H": 28, "W": 42}
        return [(name, typ, [dims.get(d, d) for d in shape]) for name, typ, shape in sig]

    outputs = concrete(OUTPUTS, None)
    outputs[0] = (outputs[0][0], outputs[0][1], [1, 4, 28, 42])         # depth baked for 4 views
    with pytest.raises(ModelError, match=r"output 'conf' dim 1 \(N\) is dynamic but output 'depth' has 4: "
                                         r"the contract's N must agree in every tensor"):
        check_da3_signature(concrete(INPUTS, None), outputs, "g.onnx")
