"""Writing exported graphs (tools/export/graph_files.py) and the export's check and card
(tools/export/da3_card.check_and_write_card), on small graphs: no torch needed."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import onnx
import pytest
from da3_contract_graph import build_da3_contract_graph
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
    """Whatever name the writer gave the data (torch's exporter: `<out>.tmp.data`; `w.bin` here), it moves
    with the graph to `<out>.data`; data spread over files, outside the graph's folder or missing is
    refused."""
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
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    onnx.save(_model(np.arange(1000.0)), str(tmp), save_as_external_data=True, location="w2.bin")
    os.replace(tmp_path / "w2.bin", elsewhere / "w2.bin")
    model = onnx.load(str(tmp), load_external_data=False)
    for entry in model.graph.initializer[0].external_data:
        if entry.key == "location":
            entry.value = "elsewhere/../elsewhere/w2.bin"
    onnx.save(model, str(tmp))
    with pytest.raises(ModelError, match="not beside it"):
        move_into_place(tmp, out)
    onnx.save(_model(np.arange(1000.0)), str(tmp), save_as_external_data=True, location="w3.bin")
    (tmp_path / "w3.bin").unlink()
    with pytest.raises(ModelError, match="w3.bin, is missing"):
        move_into_place(tmp, out)
    out.with_suffix(".json").write_text("{}")
    remove_graph(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "unused", "w"]   # not ours


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_a_failed_fp32_check_keeps_the_graph_only_when_fp32_was_asked(tmp_path, precision):
    """The fp32 graph disagrees with its references: under --precision fp32 it stays for inspection beside a
    card saying so; under fp16 no fp32 graph is left under the fp16 name, the card keeps the errors."""
    from tools.export.da3_card import check_and_write_card
    from tools.export.da3_check import check_inputs, run_graph
    from tools.export.export_da3 import ExportRequest

    inputs = check_inputs(3, 28, 42, seed=1)
    refs, _ = run_graph(build_da3_contract_graph(tmp_path / "ref.onnx"), inputs, threads=1)
    out = build_da3_contract_graph(tmp_path / f"da3_{precision}.onnx", variant="nan_depth")
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


def _external_graph(model, out: Path) -> None:
    """`model` written at `out` with its weights in `<out>.data` (a Giant-sized graph in miniature)."""
    tmp = temporary_path(out)
    onnx.save(model, str(tmp), save_as_external_data=True, location=tmp.name + ".data", size_threshold=60)
    move_into_place(tmp, out)
    assert data_path(out).exists()


@pytest.mark.parametrize("fp32_fails", [True, False])
def test_the_card_names_a_data_file_only_while_it_exists(tmp_path, fp32_fails):
    """An fp32 graph whose weights lie in `<out>.data`: removed after a failed check under --precision fp16,
    or rewritten to an fp16 graph small enough to hold its weights, it leaves no data file, and the card
    names none."""
    from test_export_fp16 import _contract_model

    from tools.export.da3_card import check_and_write_card
    from tools.export.da3_check import check_inputs, run_graph
    from tools.export.export_da3 import ExportRequest

    inputs = check_inputs(3, 28, 42, seed=1)
    out = tmp_path / "da3_fp16.onnx"
    if fp32_fails:
        refs, _ = run_graph(build_da3_contract_graph(tmp_path / "ref.onnx"), inputs, threads=1)
        _external_graph(onnx.load(build_da3_contract_graph(tmp_path / "nan.onnx", variant="nan_depth")), out)
    else:
        _external_graph(_contract_model(tmp_path), out)
        refs, _ = run_graph(out, inputs, threads=1)
    req = ExportRequest("tiny", 28, 42, str(out), random_init=True, threads=1, precision="fp16")
    card = {"precision": "fp16", "file": out.name, "parameters": 10}
    if fp32_fails:
        with pytest.raises(ModelError, match="removed: no fp16 rewrite"):
            check_and_write_card(out, inputs, refs, req, card)
    else:
        assert check_and_write_card(out, inputs, refs, req, card)["fp16"]["fp16_nodes"] == 4
    written = json.loads(out.with_suffix(".json").read_text())
    assert not data_path(out).exists() and "data_file" not in written and "data_sha256" not in written
    assert out.exists() != fp32_fails
