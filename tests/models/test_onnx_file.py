"""ONNX files as untrusted input: refused before ONNX Runtime parses them when their tensors read data
from outside the model folder, or when they break the expected contract."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import pytest
from da3_contract_graph import build_da3_contract_graph
from onnx import TensorProto, helper

from calib import Pinhole
from models.da3.contract import check_da3_signature
from models.da3.runtime import OnnxDA3
from models.inspect_model import inspect_model
from models.matcher.lighterglue import LighterGlue
from models.matcher.xfeat import XFeatDetector
from models.onnx_file import check_model_file
from models.providers import create_session
from runtime.errors import ModelError

W = np.array([1.0, 2.0], np.float32)


def external(name: str, location: str, offset: int | None = None, length: int | None = None) -> TensorProto:
    """A float tensor [2] whose data lives in `location` (as onnx's external-data format writes it)."""
    t = TensorProto(name=name, data_type=TensorProto.FLOAT, dims=[2])
    t.data_location = TensorProto.EXTERNAL
    entries = {"location": location, "offset": offset, "length": length}
    for key, value in entries.items():
        if value is not None:
            t.external_data.add(key=key, value=str(value))
    return t


def write_model(path: Path, location: str, where: str = "initializer", **kw) -> Path:
    """y = x + w with w stored externally at `location`, the tensor carried by `where`."""
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [2])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [2])
    w = external("w", location, **kw)
    nodes, inits, sparse, functions = [], [], [], []
    if where == "initializer":
        inits.append(w)
    elif where == "constant":
        nodes.append(helper.make_node("Constant", [], ["w"], value=w))
    elif where == "sparse":
        indices = helper.make_tensor("w_idx", TensorProto.INT64, [2], [0, 1])
        sparse.append(helper.make_sparse_tensor(w, indices, [2]))
    elif where == "subgraph":
        branch = helper.make_graph(
            [helper.make_node("Identity", ["w_in"], ["w_out"])], "branch", [],
            [helper.make_tensor_value_info("w_out", TensorProto.FLOAT, [2])],
            initializer=[external("w_in", location, **kw)],
        )
        cond = helper.make_tensor("cond", TensorProto.BOOL, [], [True])
        inits.append(cond)
        nodes.append(helper.make_node("If", ["cond"], ["w"], then_branch=branch, else_branch=branch))
    elif where == "function":
        fn = helper.make_function(
            "local", "weights", [], ["out"], [helper.make_node("Constant", [], ["out"], value=w)],
            opset_imports=[helper.make_opsetid("", 18)],
        )
        functions.append(fn)
        nodes.append(helper.make_node("weights", [], ["w"], domain="local"))
    nodes.append(helper.make_node("Add", ["x", "w"], ["y"]))
    graph = helper.make_graph(nodes, "g", [x], [y], initializer=inits, sparse_initializer=sparse)
    model = helper.make_model(
        graph, functions=functions,
        opset_imports=[helper.make_opsetid("", 18), helper.make_opsetid("local", 1)],
    )
    model.ir_version = 10
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(model.SerializeToString())
    return path


@pytest.fixture
def no_onnxruntime(monkeypatch):
    """Fail the test if ONNX Runtime is asked to parse a model."""

    def forbidden(*args, **kwargs):
        raise AssertionError("onnxruntime.InferenceSession was called on a refused model")

    monkeypatch.setattr(onnxruntime, "InferenceSession", forbidden)


@pytest.fixture
def layout(tmp_path) -> Path:
    """tmp/secret.bin outside the model folder tmp/model/, and links inside it that point out."""
    (tmp_path / "secret.bin").write_bytes(W.tobytes())
    folder = tmp_path / "model"
    folder.mkdir()
    os.symlink(tmp_path / "secret.bin", folder / "link.bin")
    os.symlink(tmp_path, folder / "linkdir")
    return folder


@pytest.mark.parametrize(
    "location, words",
    [
        ("../secret.bin", r"leaves the model folder \('..'\)"),
        ("sub/../../secret.bin", "leaves the model folder"),
        ("..\\secret.bin", "leaves the model folder"),
        ("/etc/passwd", "an absolute path"),
        ("C:\\Windows\\win.ini", "an absolute path"),
        ("\\\\server\\share\\w.bin", "an absolute path"),
        ("link.bin", "resolves outside the model folder"),
        ("linkdir/secret.bin", "resolves outside the model folder"),
        ("*/_ORT_MEM_ADDR_/*", "not a file in the model folder"),
        ("absent.bin", "not a file in the model folder"),
        ("", "names no file"),
    ],
)
def test_external_data_outside_the_folder_is_refused_before_onnxruntime(
    layout, no_onnxruntime, location, words
):
    path = write_model(layout / "m.onnx", location)
    with pytest.raises(ModelError, match=words) as e:
        create_session(path, providers=["CPUExecutionProvider"], threads=1)
    msg = str(e.value)
    assert msg.startswith(f"{path}: tensor 'w'") and "\n" not in msg
    if location:
        assert repr(location) in msg


@pytest.mark.parametrize("where", ["initializer", "constant", "sparse", "subgraph", "function"])
def test_every_tensor_that_can_hold_external_data_is_checked(layout, no_onnxruntime, where):
    path = write_model(layout / "m.onnx", "../secret.bin", where=where)
    with pytest.raises(ModelError, match="leaves the model folder"):
        check_model_file(path)
    with pytest.raises(ModelError, match="leaves the model folder"):
        create_session(path, providers=["CPUExecutionProvider"], threads=1)


@pytest.mark.parametrize(
    "offset, length, words",
    [
        (16, None, "offset 16, length 0"),
        (4, 8, "offset 4, length 8"),
        (-1, 8, "offset -1"),
        ("x", 8, "non-integer"),
    ],
)
def test_external_data_outside_its_file_is_refused(tmp_path, no_onnxruntime, offset, length, words):
    (tmp_path / "w.bin").write_bytes(W.tobytes())
    path = write_model(tmp_path / "m.onnx", "w.bin", offset=offset, length=length)
    with pytest.raises(ModelError, match=words):
        create_session(path, threads=1)


@pytest.mark.parametrize("location", ["w.bin", "data/w.bin", "./data/w.bin"])
def test_external_data_inside_the_folder_loads_and_runs(tmp_path, location):
    (tmp_path / location).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / location).write_bytes(b"\0" * 4 + W.tobytes())
    path = write_model(tmp_path / "m.onnx", location, offset=4, length=8)
    sess, _ = create_session(path, providers=["CPUExecutionProvider"], threads=1)
    x = np.array([10.0, 20.0], np.float32)
    np.testing.assert_array_equal(sess.run(["y"], {"x": x})[0], x + W)


def test_symlinked_model_with_its_data_beside_the_target_loads(tmp_path):
    # the Hugging Face cache layout: snapshots/<rev>/{model.onnx, w.bin} link to blobs/<hash>
    blobs, snap = tmp_path / "blobs", tmp_path / "snapshots" / "rev"
    (blobs / "data").parent.mkdir(parents=True)
    (blobs / "data").write_bytes(W.tobytes())
    write_model(blobs / "model", "w.bin")
    snap.mkdir(parents=True)
    os.symlink(blobs / "model", snap / "model.onnx")
    os.symlink(blobs / "data", snap / "w.bin")
    sess, _ = create_session(snap / "model.onnx", providers=["CPUExecutionProvider"], threads=1)
    np.testing.assert_array_equal(sess.run(["y"], {"x": np.zeros(2, np.float32)})[0], W)


def test_not_an_onnx_file_is_one_clear_line(tmp_path, no_onnxruntime):
    for name, data in [("text.onnx", b"hello, not a model\n" * 50), ("zeros.onnx", b"\xff" * 999)]:
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ModelError, match=f"{name}: not a readable ONNX model") as e:
            create_session(tmp_path / name, threads=1)
        assert "\n" not in str(e.value)


CAM = Pinhole(84, 56, 60.0, 60.0, 42.0, 28.0)


def _make_external(path: Path, name: str, location: str) -> None:
    """Move initializer `name` of the model at `path` to external data at `location`."""
    model = onnx.load(str(path))
    init = next(i for i in model.graph.initializer if i.name == name)
    init.ClearField("raw_data")
    init.data_location = TensorProto.EXTERNAL
    init.external_data.add(key="location", value=location)
    onnx.save(model, str(path))


def test_da3_runtime_refuses_a_traversing_graph_before_onnxruntime(layout, no_onnxruntime):
    path = build_da3_contract_graph(layout / "da3.onnx")
    _make_external(path, "gain", "../secret.bin")
    with pytest.raises(ModelError, match=r"da3.onnx: tensor 'gain'.*'../secret.bin'"):
        OnnxDA3(path, CAM)
    with pytest.raises(ModelError, match="leaves the model folder"):
        inspect_model(path)


@pytest.mark.parametrize("variant", ["missing_output", "wrong_dtype", "dynamic_hw", "wrong_rank"])
def test_da3_contract_is_checked_on_the_file_before_onnxruntime(tmp_path, no_onnxruntime, variant):
    path = build_da3_contract_graph(tmp_path / f"{variant}.onnx", variant=variant)
    with pytest.raises(ModelError, match=f"{variant}.onnx"):
        OnnxDA3(path, CAM)
    with pytest.raises(ModelError):
        check_model_file(path, check_da3_signature)


def test_matchers_check_their_contract_before_onnxruntime(tmp_path, no_onnxruntime):
    da3 = build_da3_contract_graph(tmp_path / "da3.onnx")
    with pytest.raises(ModelError, match="not a XFeat graph"):
        XFeatDetector(da3)
    with pytest.raises(ModelError, match="not a LighterGlue graph"):
        LighterGlue(da3)


def test_valid_da3_graph_is_unchanged(tmp_path):
    model = OnnxDA3(build_da3_contract_graph(tmp_path / "da3.onnx"), CAM, threads=1)
    assert model.graph_hw == (28, 42) and model.graph_views is None
