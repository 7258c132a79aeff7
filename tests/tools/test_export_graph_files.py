"""Writing exported graphs (tools/export/graph_files.py) and the export's check and card
(tools/export/export_da3.check_and_write_card), on small graphs: no torch needed."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from models.providers import CPU, create_session
from runtime.errors import ModelError
from tools.export.graph_files import data_path, move_into_place, remove_graph, save_graph, temporary_path

F32 = TensorProto.FLOAT


def _model(weight: np.ndarray):
    """y = x * w with w a 1000-float initializer (4 kB: external under onnx's 1 kB threshold)."""
    x = helper.make_tensor_value_info("x", F32, [1000])
    y = helper.make_tensor_value_info("y", F32, [1000])
    graph = helper.make_graph([helper.make_node("Mul", ["x", "w"], ["y"])], "g", [x], [y],
                              [numpy_helper.from_array(weight.astype(np.float32), "w")])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def _run(path: Path) -> np.ndarray:
    sess, _ = create_session(path, providers=[CPU], threads=1)
    return sess.run(None, {"x": np.ones(1000, np.float32)})[0]


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name)


def test_external_data_is_written_once_under_the_graphs_name_and_removed_when_unused(tmp_path):
    out = tmp_path / "g.onnx"
    first, second = np.arange(1000.0), -np.arange(1000.0)
    save_graph(_model(first), out, external=True)
    assert data_path(out).stat().st_size == 4000 and _leftovers(tmp_path) == []
    np.testing.assert_array_equal(_run(out), first)
    # a second graph at the same path: onnx would append its weights to an existing data file
    save_graph(_model(second), out, external=True)
    assert data_path(out).stat().st_size == 4000
    np.testing.assert_array_equal(_run(out), second)
    # a graph without external data replaces it: the stale data file goes too
    save_graph(_model(first), out, external=False)
    assert not data_path(out).exists() and _leftovers(tmp_path) == []
    np.testing.assert_array_equal(_run(out), first)


def test_a_graph_written_with_data_under_another_name_is_moved_with_it(tmp_path):
    """torch's exporter names the data after the file it writes (`<out>.tmp.data` here, `w.bin` below)."""
    out, tmp = tmp_path / "g.onnx", temporary_path(tmp_path / "g.onnx")
    onnx.save(_model(np.arange(1000.0)), str(tmp), save_as_external_data=True, location="w.bin")
    move_into_place(tmp, out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.onnx", "g.onnx.data"]
    np.testing.assert_array_equal(_run(out), np.arange(1000.0))
    # tensors spread over two files are refused
    model = _model(np.arange(1000.0))
    model.graph.initializer.append(numpy_helper.from_array(np.ones(1000, np.float32), "unused"))
    onnx.save(model, str(tmp), save_as_external_data=True, all_tensors_to_one_file=False)
    with pytest.raises(ModelError, match="spread over 2 files"):
        move_into_place(tmp, out)
    out.with_suffix(".json").write_text("{}")
    remove_graph(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["unused", "w"]   # only the per-tensor files


def _contract_graph(path: Path, variant: str = "ok") -> Path:
    spec = importlib.util.spec_from_file_location(
        "da3_contract_graph", Path(__file__).resolve().parents[1] / "models" / "da3_contract_graph.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build_da3_contract_graph(path, variant=variant)


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_a_failed_fp32_check_keeps_the_graph_only_when_fp32_was_asked(tmp_path, precision):
    """The fp32 graph disagrees with its references: under --precision fp32 it stays for inspection beside a
    card saying so; under fp16 no fp32 graph is left under the fp16 name, the card keeps the errors."""
    from tools.export.da3_check import check_inputs, run_graph
    from tools.export.export_da3 import ExportRequest, check_and_write_card

    inputs = check_inputs(3, 28, 42, seed=1)
    refs, _ = run_graph(_contract_graph(tmp_path / "ref.onnx"), inputs, threads=1)
    out = _contract_graph(tmp_path / f"da3_{precision}.onnx", variant="nan_depth")
    req = ExportRequest("tiny", 28, 42, str(out), random_init=True, threads=1, precision=precision)
    card = {"precision": precision, "file": out.name, "parameters": 10}
    with pytest.raises(ModelError, match="disagrees with torch on the fp32 graph") as err:
        check_and_write_card(out, inputs, refs, req, card)
    written = json.loads(out.with_suffix(".json").read_text())
    assert written["check"]["provider"] == CPU and written["check"]["max_rel_error"] is None   # infinite
    assert written["check"]["errors"]["cond.depth"]["nonfinite"] > 0
    if precision == "fp32":
        assert out.exists() and written["file"] == out.name and len(written["sha256"]) == 64
    else:
        assert not out.exists() and written["file"] is None and "removed" in str(err.value)
