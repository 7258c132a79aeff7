"""Checks on an ONNX file made before ONNX Runtime parses it: model files are untrusted input.

The file is read with `onnx.load(..., load_external_data=False)` (no tensor data is read from other
files) and refused, with a `ModelError` naming it, when

- it is not a readable ONNX model;
- a tensor stores its data outside the model's folder: every external-data `location` (graph and
  sub-graph initializers, sparse initializers, tensor attributes such as Constant values, local
  functions) must be a relative path that resolves, symlinks followed, to a regular file inside the
  folder, with `offset`/`length` inside that file. Absolute paths, `..`, symlinks leaving the folder
  and ONNX Runtime's in-memory markers (`*/_ORT_MEM_ADDR_/*`) are refused;
- its declared inputs and outputs break the contract the caller expects (DA3, XFeat, LighterGlue).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import TYPE_CHECKING

from runtime.errors import ModelError
from runtime.file_kind import FOLDER, MISSING, file_problem

if TYPE_CHECKING:
    import onnx

    from models.da3.contract import Signature

#: a contract check: (inputs, outputs, where) -> anything; raises ModelError on a mismatch
ContractCheck = Callable[["Signature", "Signature", str], object]

_ELEM = {
    1: "float",
    2: "uint8",
    3: "int8",
    5: "int16",
    6: "int32",
    7: "int64",
    9: "bool",
    10: "float16",
    11: "double",
    16: "bfloat16",
}


def require_file(path: Path, hint: str = "", missing: str | None = None) -> None:
    """Raise ModelError unless `path` is a regular file: "is a folder" for a directory, `missing` (default
    "model file not found: PATH") where nothing is, else what it is (a device, a broken link: see
    `runtime.file_kind`); `hint` ends each message."""
    why = file_problem(path)
    if why is None:
        return
    if why == FOLDER:
        raise ModelError(f"{path} is a folder, not an ONNX model file{hint}")
    if why == MISSING:
        raise ModelError((missing or f"model file not found: {path}") + hint)
    raise ModelError(f"{path} {why}{hint}")


def read_model(path: str | Path) -> onnx.ModelProto:
    """The model proto of `path`, without reading any external data.

    Raises:
        ModelError: missing file, or not a readable ONNX model (one line, naming the file).
    """
    import onnx

    path = Path(path)
    require_file(path)
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:
        why = " ".join(str(exc).split())[:300]
        raise ModelError(f"{path}: not a readable ONNX model ({type(exc).__name__}: {why})") from exc
    if len(model.graph.node) == 0:
        raise ModelError(f"{path}: not a readable ONNX model (the graph has no nodes)")
    return model


def _graph_tensors(graph) -> Iterator:
    yield from graph.initializer
    for sparse in graph.sparse_initializer:
        yield from (sparse.values, sparse.indices)
    yield from _node_tensors(graph.node)


def _node_tensors(nodes) -> Iterator:
    for node in nodes:
        for attr in node.attribute:
            if attr.HasField("t"):
                yield attr.t
            yield from attr.tensors
            sparse = list(attr.sparse_tensors)
            if attr.HasField("sparse_tensor"):
                sparse.append(attr.sparse_tensor)
            for st in sparse:
                yield from (st.values, st.indices)
            if attr.HasField("g"):
                yield from _graph_tensors(attr.g)
            for g in attr.graphs:
                yield from _graph_tensors(g)


def all_tensors(model: onnx.ModelProto) -> Iterator:
    """Every TensorProto of the model that can carry data: initializers (dense and sparse) of the
    graph, of every sub-graph and of training graphs, tensor attributes, local functions' nodes."""
    yield from _graph_tensors(model.graph)
    for function in model.functions:
        yield from _node_tensors(function.node)
    for info in model.training_info:
        yield from _graph_tensors(info.initialization)
        yield from _graph_tensors(info.algorithm)


def _is_absolute(location: str) -> bool:
    win = PureWindowsPath(location)
    return PurePosixPath(location).is_absolute() or bool(win.drive or win.root)


def check_external_data(model: onnx.ModelProto, path: str | Path) -> None:
    """Refuse a model whose tensors read data from outside its folder (see the module docstring).

    Raises:
        ModelError: naming the model file, the tensor and its `location`.
    """
    from onnx import TensorProto

    path = Path(path)
    folder = Path(os.path.realpath(path.parent))
    # a symlinked model file (Hugging Face cache: snapshots/ -> blobs/) may have its data beside its target
    folders = (folder, Path(os.path.realpath(path)).parent)
    for tensor in all_tensors(model):
        if tensor.data_location != TensorProto.EXTERNAL and not tensor.external_data:
            continue
        info = {e.key: e.value for e in tensor.external_data}
        location = info.get("location", "")
        where = f"{path}: tensor '{tensor.name}' stores its data in external file {location!r}"
        fix = "external data must be files beside the model (re-export or re-save it with onnx)"
        if not location:
            raise ModelError(f"{path}: tensor '{tensor.name}' is marked external but names no file; {fix}")
        if _is_absolute(location):
            raise ModelError(f"{where}, an absolute path; {fix}")
        if ".." in location.replace("\\", "/").split("/"):
            raise ModelError(f"{where}, which leaves the model folder ('..'); {fix}")
        target = Path(os.path.realpath(folder / location))
        if not any(target.is_relative_to(f) for f in folders):
            raise ModelError(f"{where}, which resolves outside the model folder (to {target}); {fix}")
        if not target.is_file():
            raise ModelError(f"{where}, which is not a file in the model folder {folder}; {fix}")
        try:
            offset, length = int(info.get("offset", 0)), int(info.get("length", 0))
        except ValueError as exc:
            raise ModelError(f"{where} with a non-integer offset or length ({exc})") from exc
        size = target.stat().st_size
        if offset < 0 or length < 0 or offset + length > size:
            raise ModelError(
                f"{where} at offset {offset}, length {length}: outside the {size}-byte file"
            )


def graph_signature(values) -> list[tuple[str, str, list]]:
    """ONNX ValueInfo list -> contract signature (ORT type strings, int or None dims)."""
    out = []
    for v in values:
        tt = v.type.tensor_type
        dims = [d.dim_value if d.HasField("dim_value") else None for d in tt.shape.dim]
        out.append((v.name, f"tensor({_ELEM.get(tt.elem_type, str(tt.elem_type))})", dims))
    return out


def model_signature(model: onnx.ModelProto) -> tuple[list, list]:
    """(inputs, outputs) the graph declares, as contract signatures (initializers are not inputs)."""
    inits = {i.name for i in model.graph.initializer}
    inputs = graph_signature([v for v in model.graph.input if v.name not in inits])
    return inputs, graph_signature(model.graph.output)


def check_model_file(path: str | Path, contract: ContractCheck | None = None) -> onnx.ModelProto:
    """Read `path` and check it before ONNX Runtime may parse it; returns the model proto.

    Args:
        path: the .onnx file.
        contract: e.g. `check_da3_signature`, applied to the declared inputs and outputs.

    Raises:
        ModelError: unreadable file, external data outside the model folder, or a contract mismatch.
    """
    model = read_model(path)
    check_external_data(model, path)
    if contract is not None:
        contract(*model_signature(model), str(path))
    return model
