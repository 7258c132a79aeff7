"""Contract-only DA3 graphs built with onnx.helper (no weights), with known, checkable outputs.

    depth           = 2 + 0.5 * images[:, :, 0]        (the normalised red channel)
    conf            = 1 + |images[:, :, 1]|
    pred_extrinsics = extrinsics[:, :, :3, :] with the translation column times `t_gain`
    pred_intrinsics = use_pose ? intrinsics : [[f, 0, W/2], [0, f, H/2], [0, 0, 1]]
Variants break one clause of the contract to exercise the loader's errors ("fixed_n" is valid: N = 4);
"nan_depth" declares a valid signature but computes NaN depth, "negative_depth" negative depth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


def build_da3_contract_graph(
    path: Path, h: int = 28, w: int = 42, t_gain: float = 2.0, focal: float = 30.0, variant: str = "ok"
) -> Path:
    """Write a contract graph (or a broken `variant`) to `path`; returns the path."""
    f32, b = TensorProto.FLOAT, TensorProto.BOOL
    H, W = ("H" if variant == "dynamic_hw" else h), ("W" if variant == "dynamic_hw" else w)
    img_type = {"wrong_dtype": TensorProto.DOUBLE, "fp16_images": TensorProto.FLOAT16}.get(variant, f32)
    N = 4 if variant == "fixed_n" else "N"
    inputs = [
        helper.make_tensor_value_info("images", img_type, [1, N, 3, H, W]),
        helper.make_tensor_value_info("intrinsics", f32, [1, N, 3, 3]),
        helper.make_tensor_value_info("extrinsics", f32, [1, N, 4, 4]),
        helper.make_tensor_value_info("use_pose", b, [1]),
    ]
    depth_shape = [1, N, H, W] if variant != "wrong_rank" else [1, N, H, W, 1]
    outputs = [
        helper.make_tensor_value_info("depth", f32, depth_shape),
        helper.make_tensor_value_info("conf", f32, [1, N, H, W]),
        helper.make_tensor_value_info("pred_extrinsics", f32, [1, N, 3, 4]),
        helper.make_tensor_value_info("pred_intrinsics", f32, [1, N, 3, 3]),
    ]
    if variant == "missing_output":
        outputs = outputs[:3]
    gain = np.ones((1, 1, 3, 4), np.float32)
    gain[..., 3] = t_gain
    K_const = np.array([[focal, 0, w / 2], [0, focal, h / 2], [0, 0, 1]], np.float32)
    inits = [
        numpy_helper.from_array(np.array(v, np.int64), n)
        for n, v in [("c0", [0]), ("c1", [1]), ("c2", [2]), ("c3", [3]), ("ax2", [2])]
    ]
    inits += [
        numpy_helper.from_array(np.array(0.5, np.float32), "half"),
        numpy_helper.from_array(np.array(2.0, np.float32), "two"),
        numpy_helper.from_array(np.array(1.0, np.float32), "one"),
        numpy_helper.from_array(gain, "gain"),
        numpy_helper.from_array(K_const, "K_const"),
    ]
    img = "images_f" if img_type != f32 else "images"
    nodes = []
    if img_type != f32:
        nodes.append(helper.make_node("Cast", ["images"], ["images_f"], to=f32))
    nodes += [
        helper.make_node("Slice", [img, "c0", "c1", "ax2"], ["red5"]),
        helper.make_node("Squeeze", ["red5", "ax2"], ["red"]),
        helper.make_node("Mul", ["red", "half"], ["red_half"]),
        helper.make_node("Add", ["red_half", "two"], ["depth"]),
        helper.make_node("Slice", [img, "c1", "c2", "ax2"], ["green5"]),
        helper.make_node("Squeeze", ["green5", "ax2"], ["green"]),
        helper.make_node("Abs", ["green"], ["green_abs"]),
        helper.make_node("Add", ["green_abs", "one"], ["conf"]),
        helper.make_node("Slice", ["extrinsics", "c0", "c3", "ax2"], ["E34"]),
        helper.make_node("Mul", ["E34", "gain"], ["pred_extrinsics"]),
        helper.make_node("Where", ["use_pose", "intrinsics", "K_const"], ["pred_intrinsics"]),
    ]
    if variant == "wrong_rank":
        nodes[3] = helper.make_node("Add", ["red_half", "two"], ["depth4"])
        nodes.append(helper.make_node("Unsqueeze", ["depth4", "ax_last"], ["depth"]))
        inits.append(numpy_helper.from_array(np.array([4], np.int64), "ax_last"))
    if variant == "nan_depth":
        nodes[3] = helper.make_node("Add", ["red_half", "two"], ["depth_ok"])
        inits.append(numpy_helper.from_array(np.array(np.nan, np.float32), "nan"))
        nodes.append(helper.make_node("Mul", ["depth_ok", "nan"], ["depth"]))
    if variant == "negative_depth":   # a valid, finite signature whose depth is never positive
        nodes[3] = helper.make_node("Add", ["red_half", "two"], ["depth_ok"])
        inits.append(numpy_helper.from_array(np.array(-1.0, np.float32), "minus"))
        nodes.append(helper.make_node("Mul", ["depth_ok", "minus"], ["depth"]))
    if variant == "log_conf":          # log(conf): negative where the confidence is below e
        nodes[7] = helper.make_node("Add", ["green_abs", "one"], ["conf_lin"])
        nodes.append(helper.make_node("Log", ["conf_lin"], ["conf_log"]))
        nodes.append(helper.make_node("Sub", ["conf_log", "one"], ["conf"]))
    if variant == "missing_output":
        nodes = [n for n in nodes if n.output[0] != "pred_intrinsics"]
    graph = helper.make_graph(nodes, "da3_contract", inputs, outputs, inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], producer_name="davio-tests")
    model.ir_version = 9
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path
