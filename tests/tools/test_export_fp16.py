"""Mixed-precision DA3 graphs (tools/export/fp16.py): which nodes go to fp16; the rest stays untouched."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from da3_contract_graph import build_da3_contract_graph
from onnx import TensorProto, helper, numpy_helper

from runtime.errors import ModelError
from tools.export.fp16 import SCOPE_KEY, graph_precision, to_mixed_fp16

F32, F16 = TensorProto.FLOAT, TensorProto.FLOAT16


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


def test_exp_and_friends_compute_in_fp32_inside_the_backbone():
    """An Exp in the region computes in float32 (its output tensor is F32, the Mul after it reads an fp16
    cast of it). ONNX Runtime's CPU provider computes fp16 arithmetic in fp32, so a CPU run could not show
    an fp16 overflow: the types are what this test checks, and the values within fp16 rounding."""
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
    feeds = {"x": np.array([3.0, 1.0, -3.0, 0.1], np.float32)}    # exp(6) = 403: finite in fp16
    ref = _run(model, feeds)[0]
    half, summary = to_mixed_fp16(model)
    assert summary["fp16_ops"] == {"Mul": 2}
    types = _types(half)
    assert types["e"] == F32 and types["x2__fp16"] == F16 and types["y__fp16"] == F16
    exp = next(n for n in half.graph.node if n.op_type == "Exp")
    assert exp.input[0] != "x2__fp16" and exp.output[0] == "e"    # reads a float32 cast back
    np.testing.assert_allclose(_run(half, feeds)[0], ref, rtol=3 * 2.0**-11)


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


def _region_model(nodes, inputs, outputs, inits=(), opset: int = 23):
    for node in nodes:
        _scope(node, "net.backbone")
    return helper.make_model(helper.make_graph(nodes, "g", inputs, outputs, list(inits)),
                             opset_imports=[helper.make_opsetid("", opset)])


def test_values_that_feed_float32_only_inputs_are_not_rounded():
    """Resize scales computed in the region (0.57 = 0.5 + 0.07): through fp16 they would round to 0.5698 and
    the output width of 100 pixels would be 56, not 57; the scale chain stays fp32."""
    x = helper.make_tensor_value_info("x", F32, [1, 1, 1, 100])
    y = helper.make_tensor_value_info("y", F32, None)
    nodes = [
        helper.make_node("Add", ["a", "b"], ["sx"], name="scale_x"),
        helper.make_node("Concat", ["ones", "sx"], ["scales"], axis=0, name="scales"),
        helper.make_node("Mul", ["x", "two"], ["x2"], name="mul"),
        helper.make_node("Resize", ["x2", "", "scales"], ["y"], mode="linear", name="resize"),
    ]
    inits = [numpy_helper.from_array(np.array([0.5], np.float32), "a"),
             numpy_helper.from_array(np.array([0.07], np.float32), "b"),
             numpy_helper.from_array(np.ones(3, np.float32), "ones"),
             numpy_helper.from_array(np.array(2.0, np.float32), "two")]
    model = _region_model(nodes, [x], [y], inits)
    feeds = {"x": np.linspace(0, 1, 100, dtype=np.float32).reshape(1, 1, 1, 100)}
    ref = _run(model, feeds)[0]
    half, summary = to_mixed_fp16(model)
    assert summary["fp16_ops"] == {"Mul": 1, "Resize": 1}     # Add and Concat build the scales in fp32
    got = _run(half, feeds)[0]
    assert got.shape == ref.shape == (1, 1, 1, 57)
    np.testing.assert_allclose(got, ref, atol=2e-3)


def test_a_scale_chain_through_an_fp32_op_is_not_rounded():
    """Scales 1 / (1000 + 0.3) built in the region with a Reciprocal (an op kept fp32 wherever it sits): in
    fp16 the sum rounds to 1000.5 and 5002 pixels would give floor(4.9995) = 4, not floor(5.0005) = 5. The
    Add feeds the float32-only input only through the Reciprocal: it stays fp32 as well."""
    x = helper.make_tensor_value_info("x", F32, [1, 1, 1, 5002])
    y = helper.make_tensor_value_info("y", F32, None)
    nodes = [
        helper.make_node("Add", ["a", "b"], ["s"], name="sum"),
        helper.make_node("Reciprocal", ["s"], ["rs"], name="reciprocal"),
        helper.make_node("Concat", ["ones", "rs"], ["scales"], axis=0, name="scales"),
        helper.make_node("Mul", ["x", "two"], ["x2"], name="mul"),
        helper.make_node("Resize", ["x2", "", "scales"], ["y"], mode="nearest", name="resize"),
    ]
    inits = [numpy_helper.from_array(np.array([1000.0], np.float32), "a"),
             numpy_helper.from_array(np.array([0.3], np.float32), "b"),
             numpy_helper.from_array(np.ones(3, np.float32), "ones"),
             numpy_helper.from_array(np.array(2.0, np.float32), "two")]
    model = _region_model(nodes, [x], [y], inits)
    feeds = {"x": np.linspace(0, 1, 5002, dtype=np.float32).reshape(1, 1, 1, 5002)}
    ref = _run(model, feeds)[0]
    half, summary = to_mixed_fp16(model)
    assert summary["fp16_ops"] == {"Mul": 1, "Resize": 1}
    got = _run(half, feeds)[0]
    assert got.shape == ref.shape == (1, 1, 1, 5)
    np.testing.assert_allclose(got, ref, atol=2e-3)


def test_untyped_tensors_keep_their_nodes_in_fp32():
    """A custom-domain node's output has no type ONNX can infer: the node reading it stays fp32 (it was
    given an fp16 weight beside an fp32 activation before, which ONNX Runtime refused)."""
    x = helper.make_tensor_value_info("x", F32, [4])
    y = helper.make_tensor_value_info("y", F32, [4])
    nodes = [
        helper.make_node("Gelu", ["x"], ["a"], domain="com.microsoft", name="gelu"),
        helper.make_node("Mul", ["a", "w"], ["b"], name="mul"),
        helper.make_node("Add", ["x", "w"], ["y0"], name="add"),
        helper.make_node("Add", ["b", "y0"], ["y"], name="sum"),
    ]
    model = _region_model(nodes, [x], [y], [numpy_helper.from_array(np.full(4, 1.5, np.float32), "w")])
    model.opset_import.append(helper.make_opsetid("com.microsoft", 1))
    feeds = {"x": np.array([0.5, -1.0, 2.0, 0.0], np.float32)}
    ref = _run(model, feeds)[0]
    half, summary = to_mixed_fp16(model)
    assert summary["fp16_ops"] == {"Add": 1}       # only the Add of typed tensors
    np.testing.assert_allclose(_run(half, feeds)[0], ref, rtol=2e-3)


def test_names_stay_unique_and_fed_initializers_are_cast():
    """A tensor already called `a__fp16` gets no twin of the same name; an initializer that is also a graph
    input is cast at run time (its fed value counts), not frozen to its default; subgraphs are refused."""
    x = helper.make_tensor_value_info("x", F32, [4])
    w_in = helper.make_tensor_value_info("w", F32, [4])
    y = helper.make_tensor_value_info("y", F32, [4])
    nodes = [
        helper.make_node("Mul", ["x", "w"], ["a"], name="mul"),
        helper.make_node("Neg", ["a"], ["a__fp16"], name="x__to_fp16_cast"),   # a name the rewrite would use
        helper.make_node("Sub", ["a", "a__fp16"], ["y"], name="sub"),      # y = 2 x w
    ]
    model = _region_model(nodes, [x, w_in], [y], [numpy_helper.from_array(np.ones(4, np.float32), "w")])
    half, _ = to_mixed_fp16(model)
    onnx.checker.check_model(half, full_check=True)
    produced = [o for n in half.graph.node for o in n.output]
    assert len(produced) == len(set(produced))
    names = [n.name for n in half.graph.node]
    assert len(names) == len(set(names)) and "x__to_fp16_cast" in names
    x_val = np.arange(4, dtype=np.float32)
    np.testing.assert_array_equal(_run(half, {"x": x_val})[0], 2 * x_val)              # the default w = 1
    np.testing.assert_array_equal(_run(half, {"x": x_val, "w": np.full(4, 3.0, np.float32)})[0], 6 * x_val)
    # a graph *input* named `a__fp16` keeps its name: the fp16 twin of `a` must be called otherwise
    taken = helper.make_tensor_value_info("a__fp16", F32, [4])
    nodes = [helper.make_node("Mul", ["x", "w"], ["a"], name="mul"),
             helper.make_node("Sub", ["a", "a__fp16"], ["y"], name="sub")]
    ones = numpy_helper.from_array(np.ones(4, np.float32), "w")
    model = _region_model(nodes, [x, w_in, taken], [y], [ones])
    half, _ = to_mixed_fp16(model)
    onnx.checker.check_model(half, full_check=True)
    np.testing.assert_array_equal(_run(half, {"x": x_val, "a__fp16": np.ones(4, np.float32)})[0], x_val - 1)
    branch = helper.make_graph([helper.make_node("Identity", ["x"], ["z"])], "b", [],
                               [helper.make_tensor_value_info("z", F32, [4])])
    cond = helper.make_node("If", ["c"], ["y"], then_branch=branch, else_branch=branch, name="if")
    with_if = _region_model([cond], [helper.make_tensor_value_info("c", TensorProto.BOOL, [])], [y])
    with pytest.raises(ModelError, match="subgraphs"):
        to_mixed_fp16(with_if)


def test_the_export_checks_count_non_finite_outputs_and_remove_a_failed_rewrite(tmp_path):
    """The export's check: a graph computing NaN depth is infinitely wrong (a plain max() over the errors let
    a NaN through); the fp16 stage on a scoped graph checks against the references and the fp32 graph on the
    same provider; a rewrite that fails removes the file and its card instead of leaving an fp32 graph under
    the fp16 name."""
    from tools.export.da3_card import fp16_rewrite_and_check
    from tools.export.da3_check import check_inputs, compare_with_onnxruntime, run_graph, worst_error
    from tools.export.export_da3 import ExportRequest

    inputs = check_inputs(3, 28, 42, seed=1)
    ok = build_da3_contract_graph(tmp_path / "ok.onnx")
    refs, provider = run_graph(ok, inputs, threads=1)
    assert provider == "CPUExecutionProvider"
    assert worst_error(compare_with_onnxruntime(ok, inputs, refs, threads=1)[0]) == 0.0
    nan = build_da3_contract_graph(tmp_path / "nan.onnx", variant="nan_depth")
    errors, _ = compare_with_onnxruntime(nan, inputs, refs, threads=1)
    assert errors["cond.depth"]["nonfinite"] > 0 and errors["cond.conf"]["nonfinite"] == 0
    assert worst_error(errors) == float("inf")
    # a NaN in the reference (the fp32 graph's outputs in the fp16-against-fp32 check) counts as well
    nan_refs, _ = run_graph(nan, inputs, threads=1)
    errors, _ = compare_with_onnxruntime(ok, inputs, nan_refs, threads=1)
    assert errors["uncond.depth"]["nonfinite"] > 0 and worst_error(errors) == float("inf")

    scoped = tmp_path / "scoped_fp16.onnx"
    onnx.save(_contract_model(tmp_path), scoped)
    req = ExportRequest("tiny", 28, 42, str(scoped), random_init=True, threads=1, precision="fp16")
    summary, check = fp16_rewrite_and_check(scoped, inputs, refs, req)
    assert summary["fp16_nodes"] == 4 and check["provider"] == "CPUExecutionProvider"
    assert check["vs_fp32"]["fp32_provider"] == "CPUExecutionProvider"
    assert 0 < check["vs_fp32"]["max_rel_error"] < 1e-3 and check["tolerance"] == 0.1
    assert check["errors"]["uncond.conf"]["max_abs"] == 0.0      # outside the region: exact
    assert graph_precision(onnx.load(scoped)) == "fp16"

    bare = build_da3_contract_graph(tmp_path / "bare_fp16.onnx")
    bare.with_suffix(".json").write_text("{}")    # a card from an earlier export at this path
    req = ExportRequest("tiny", 28, 42, str(bare), random_init=True, threads=1, precision="fp16")
    with pytest.raises(ModelError, match="fp16 rewrite failed on CPUExecutionProvider.*nothing was written"):
        fp16_rewrite_and_check(bare, inputs, refs, req)
    assert not bare.exists() and not bare.with_suffix(".json").exists()
