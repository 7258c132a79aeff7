"""`davio info --model PATH`: recognise an ONNX file's contract (DA3, XFeat, LighterGlue) and validate it."""

from __future__ import annotations

import json
from pathlib import Path

from runtime.errors import ModelError

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


def _graph_signature(values) -> list[tuple[str, str, list]]:
    """ONNX ValueInfo list -> contract signature (ORT type strings, int or None dims)."""
    out = []
    for v in values:
        tt = v.type.tensor_type
        dims = [d.dim_value if d.HasField("dim_value") else None for d in tt.shape.dim]
        out.append((v.name, f"tensor({_ELEM.get(tt.elem_type, str(tt.elem_type))})", dims))
    return out


def model_card_path(path: str | Path) -> Path:
    """The model card written beside a graph by the export tools: same stem, `.json`."""
    return Path(path).with_suffix(".json")


def inspect_model(path: str | Path, load_session: bool = True) -> dict:
    """Validate an ONNX model against the DA3 or XFeat contract and describe it.

    Args:
        path: the .onnx file.
        load_session: also create an ONNX Runtime (CPU) session, proving the runtime can load it.

    Returns:
        dict with contract, inputs, outputs, resolution (DA3) or dynamic size note (XFeat), opset,
        file size, producer, metadata and the model card (when a `.json` sits beside the graph).

    Raises:
        ModelError: the file is missing, is not a readable ONNX model, or matches neither contract.
    """
    import onnx

    from models.da3.contract import check_da3_signature
    from models.matcher.contract import check_lighterglue_signature, check_xfeat_signature

    path = Path(path)
    if not path.is_file():
        raise ModelError(
            f"model file not found: {path} (export DA3 with `davio export-da3`, XFeat with "
            "`davio export-xfeat`)"
        )
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:
        raise ModelError(f"{path}: not a readable ONNX model ({type(exc).__name__}: {exc})") from exc
    if len(model.graph.node) == 0:
        raise ModelError(f"{path}: not a readable ONNX model (the graph has no nodes)")
    inits = {i.name for i in model.graph.initializer}
    inputs = _graph_signature([v for v in model.graph.input if v.name not in inits])
    outputs = _graph_signature(model.graph.output)
    names = {n for n, _, _ in inputs}
    where = str(path)
    info: dict = {"path": str(path), "size_bytes": path.stat().st_size}
    if "images" in names:
        h, w = check_da3_signature(inputs, outputs, where)
        info.update(contract="davio.da3", resolution=[h, w])
    elif "image" in names:
        check_xfeat_signature(inputs, outputs, where)
        info.update(contract="davio.xfeat_backbone", resolution="dynamic (H, W multiples of 8)")
    elif "kpts0" in names:
        check_lighterglue_signature(inputs, outputs, where)
        info.update(contract="davio.lighterglue", resolution="dynamic (M, N keypoints)")
    else:
        raise ModelError(
            f"{where}: matches neither the DA3 contract (inputs images, intrinsics, extrinsics, "
            f"use_pose), the XFeat one (input image) nor the LighterGlue one (kpts0, kpts1, desc0, desc1); "
            f"inputs are {sorted(names)}"
        )
    info["inputs"] = [{"name": n, "type": t, "shape": s} for n, t, s in inputs]
    info["outputs"] = [{"name": n, "type": t, "shape": s} for n, t, s in outputs]
    info["opset"] = {o.domain or "ai.onnx": o.version for o in model.opset_import}
    info["producer"] = f"{model.producer_name} {model.producer_version}".strip()
    info["metadata"] = {p.key: p.value for p in model.metadata_props}
    card = model_card_path(path)
    if card.is_file():
        try:
            info["model_card"] = json.loads(card.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ModelError(f"{card}: model card is not valid JSON ({exc})") from exc
    else:
        info["model_card"] = None
    del model
    if load_session:
        from models.providers import create_session

        _, sinfo = create_session(path, providers=["CPUExecutionProvider"], threads=1)
        info["onnxruntime"] = "loads on CPUExecutionProvider"
    return info
