"""Mixed-precision DA3 graphs (tools/export/fp16.py): which nodes go to fp16; the rest stays untouched."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from runtime.errors import ModelError
from tools.export.fp16 import SCOPE_KEY, graph_precision, to_mixed_fp16

F32, F16 = TensorProto.FLOAT, TensorProto.FLOAT16


def build_da3_contract_graph(path: Path) -> Path:
    """tests/models/da3_contract_graph.py's contract graph (that folder is not on this file's path)."""
    spec = importlib.util.spec_from_file_location(
        "da3_contract_graph", Path(__file__).resolve().parents[1] / "models" / "da3_contract_graph.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.build_da3_contract_graph(path)


def _scope(node, module: str) -> None:
    """Record `module` as the node's module path the way torch's dynamo exporter does."""
    parts = module.split(".")
    scopes = [""] + [".".join(parts[: i + 1]) for i in range(len(parts))] + [node.name or node.op_type]
    node.metadata_props.add(key=SCOPE_KEY, value=repr(scopes))


def _run(model, feeds: dict) -> list[np.ndarray]:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, feeds)


def _types(model) -> dict[str, int]:
    inferred = onnx.shape_inference.infer_shapes(model, strict_mode=True)
    g = inferred.graph
    return {v.name: v.type.tensor_type.elem_type for v in list(g.value_info) + list(g.output) + list(g.input)}


def _contract_model(tmp_path: Path):
    """The contract graph with its depth branch (first four nodes) in `net.backbone`, the rest in a head."""
    model = onnx.load(build_da3_contract_graph(tmp_path / "c.onnx"))
    for i, node in enumerate(model.graph.node):
        _scope(node, "net.backbone.blocks.0" if i < 4 else "net.head")
    return model


def _feeds(n: int = 3, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {
        "images": rng.normal(size=(1, n, 3, 28, 42)).astype(np.float32),
        "intrinsics": rng.normal(size=(1, n, 3, 3)).astype(np.float32),
        "extrinsics": rng.normal(size=(1, n, 4, 4)).astype(np.float32),
        "use_pose": np.array([True]),
    }


def test_backbone_nodes_compute_in_fp16_and_the_rest_is_bit_identical(tmp_path):
    model = _contract_model(tmp_path)
    feeds = _feeds()
    ref = _run(model, feeds)
    assert graph_precision(model) == "fp32"
    half, summary = to_mixed_fp16(model)
    onnx.checker.check_model(half, full_check=True)
    assert graph_precision(half) == "fp16"
    assert summary["fp16_nodes"] == 4 and summary["fp32_nodes"] == 7 and summary["unscoped_nodes"] == 0
    assert summary["fp16_ops"] == {"Add": 1, "Mul": 1, "Slice": 1, "Squeeze": 1}
    # the contract's inputs and outputs keep float32; the backbone's tensors are float16
    assert [i.type.tensor_type.elem_type for i in half.graph.input][:3] == [F32] * 3
    assert {o.type.tensor_type.elem_type for o in half.graph.output} == {F32}
    types = _types(half)
    assert types["red_half__fp16"] == F16 and types["green_abs"] == F32
    got = _run(half, feeds)
    for name, g, r in zip(["depth", "conf", "pred_extrinsics", "pred_intrinsics"], got, ref, strict=True):
        assert g.dtype == np.float32, name
        if name != "depth":
            np.testing.assert_array_equal(g, r, err_msg=name)   # nodes outside the backbone untouched
    # depth = 2 + 0.5 * red from the fp16-rounded image, rounded to fp16 at the end: each rounding at most
    # 2^-11 relative (ONNX Runtime's CPU provider may compute the fp16 arithmetic itself in fp32)
    red = feeds["images"][:, :, 0]
    bound = 2.0**-11 * (0.5 * np.abs(red) + np.abs(ref[0])) * 1.01
    assert np.all(np.abs(got[0] - ref[0]) <= bound)
    assert np.abs(got[0] - ref[0]).max() > 0


def test_exp_and_friends_stay_fp32_inside_the_backbone():
    """exp(12) = 162755 overflows fp16 (max 65504): the Exp node keeps float32 and the result is finite."""
    x = helper.make_tensor_value_info("x", F32, [4])
    y = helper.make_tensor_value_info("y", F32, [4])
    nodes = [
        helper.make_node("Mul", ["x", "two"], ["x2"], name="mul"),
        helper.make_node("Exp", ["x2"], ["e"], name="exp"),
        helper.make_node("Mul", ["e", "half"], ["y"], name="scale"),
    ]
    for node in nodes:
        _scope(node, "net.backbone.head_of_backbone")
    inits = [numpy_helper.from_array(np.array(2.0, np.float32), "two"),
             numpy_helper.from_array(np.array(0.5, np.float32), "half")]
    model = helper.make_model(helper.make_graph(nodes, "g", [x], [y], inits),
                              opset_imports=[helper.make_opsetid("", 23)])
    feeds = {"x": np.array([6.0, 1.0, -3.0, 0.1], np.float32)}
    ref = _run(model, feeds)[0]
    half, summary = to_mixed_fp16(model)
    assert summary["fp16_ops"] == {"Mul": 2}
    types = _types(half)
    assert types["e"] == F32 and types["x2__fp16"] == F16
    got = _run(half, feeds)[0]
    assert np.isfinite(got).all()
    # e is exact fp32; the last Mul runs in fp16 on e's fp16 rounding, and exp(12) / 2 fits fp16 again
    np.testing.assert_allclose(got, ref, rtol=1e-3)


def test_attribute_typed_outputs_and_float32_only_inputs():
    """Cast(to=float), Constant(value_float), ConstantOfShape inside the backbone emit fp16; Resize's scales
    stay float32 as ONNX types them; the strict type check of onnx passes."""
    x = helper.make_tensor_value_info("x", F32, [1, 1, 2, 3])
    y = helper.make_tensor_value_info("y", F32, [1, 1, 4, 6])
    nodes = [
        helper.make_node("Shape", ["x"], ["shape"], name="shape"),
        helper.make_node("Cast", ["shape"], ["shape_f"], to=F32, name="cast"),
        helper.make_node("ReduceSum", ["shape_f"], ["total"], keepdims=0, name="sum"),
        helper.make_node("Constant", [], ["c"], value_float=0.25, name="const"),
        helper.make_node("ConstantOfShape", ["shape"], ["zeros"], name="zeros"),
        helper.make_node("Add", ["x", "zeros"], ["x0"], name="add0"),
        helper.make_node("Mul", ["total", "c"], ["k"], name="mulk"),
        helper.make_node("Add", ["x0", "k"], ["x1"], name="add1"),
        helper.make_node("Resize", ["x1", "", "scales"], ["y"], mode="nearest", name="resize"),
    ]
    for node in nodes:
        _scope(node, "net.backbone")
    scales = numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), "scales")
    model = helper.make_model(helper.make_graph(nodes, "g", [x], [y], [scales]),
                              opset_imports=[helper.make_opsetid("", 23)])
    half, _ = to_mixed_fp16(model)
    onnx.checker.check_model(half, full_check=True)
    types = _types(half)
    assert types["shape_f__fp16"] == F16 and types["c__fp16"] == F16 and types["zeros__fp16"] == F16
    resize = next(n for n in half.graph.node if n.op_type == "Resize")
    assert resize.input[2] == "scales"
    assert {t.name: t.data_type for t in half.graph.initializer}["scales"] == F32


def test_graphs_without_scopes_or_without_the_module_are_refused(tmp_path):
    bare = onnx.load(build_da3_contract_graph(tmp_path / "c.onnx"))
    with pytest.raises(ModelError, match="module scopes"):
        to_mixed_fp16(bare, where="bare.onnx")
    model = _contract_model(tmp_path)
    with pytest.raises(ModelError, match="no node lies inside module 'net.encoder'"):
        to_mixed_fp16(model, scope="net.encoder")
    # 'net.backbone2' is not inside 'net.backbone'
    for node in model.graph.node:
        del node.metadata_props[:]
        _scope(node, "net.backbone2")
    with pytest.raises(ModelError, match="no node lies inside"):
        to_mixed_fp16(model)


def test_an_fp16_graph_is_a_drop_in_graph_reported_as_fp16(tmp_path, caplog):
    """OnnxDA3 runs the rewritten contract graph unchanged, reports its precision, and warns on the CPU
    provider; `davio info --model` says fp16 (beside the opset-18 note when both apply)."""
    from calib import Pinhole
    from models.da3 import OnnxDA3
    from models.inspect_model import inspect_model
    from runtime.events import Frame

    half, _ = to_mixed_fp16(_contract_model(tmp_path))
    path = tmp_path / "da3_fp16.onnx"
    onnx.save(half, path)
    cam = Pinhole(42, 28, 30.0, 30.0, 20.5, 13.5)
    with caplog.at_level("WARNING", logger="models.da3.runtime"):
        model = OnnxDA3(path, cam, providers=["CPUExecutionProvider"], threads=1)
    assert model.precision == "fp16" and model.session_info["precision"] == "fp16"
    assert "fp16 graph for GPUs" in caplog.text and "--precision fp32" in caplog.text
    rng = np.random.default_rng(1)
    frames = [Frame(i, rng.integers(0, 255, (28, 42), dtype=np.uint8)) for i in range(3)]
    pred = model.predict(frames)
    assert pred.info["precision"] == "fp16" and np.isfinite(pred.depth).all()
    # the fp32 graph: no warning, fp32
    caplog.clear()
    fp32 = build_da3_contract_graph(tmp_path / "da3_fp32.onnx")
    with caplog.at_level("WARNING", logger="models.da3.runtime"):
        assert OnnxDA3(fp32, cam, providers=["CPUExecutionProvider"], threads=1).precision == "fp32"
    assert "fp16" not in caplog.text
    info = inspect_model(path)
    assert info["precision"] == "fp16" and "fp16 graph" in info["note"]
    assert inspect_model(fp32)["precision"] == "fp32" and "note" not in inspect_model(fp32)
    half.graph.node.append(helper.make_node("Softmax", ["images"], ["attn_probs"], axis=-1))
    onnx.save(half, path)
    note = inspect_model(path)["note"]
    assert "an opset-18 export" in note and "fp16 graph" in note
