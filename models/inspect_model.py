"""`davio info --model PATH`: recognise an ONNX file's contract (DA3, XFeat, LighterGlue) and validate it."""

from __future__ import annotations

import json
from pathlib import Path

from models.onnx_file import check_model_file, model_signature, require_file
from runtime.errors import ModelError


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
        ModelError: the file is missing, is not a readable ONNX model, reads external data from
            outside its folder, or matches no contract.
    """
    from models.da3.contract import FIXED_VIEWS_HINT, PRECISION_KEY, WINDOW_VIEWS, check_da3_signature
    from models.matcher.contract import check_lighterglue_signature, check_xfeat_signature

    path = Path(path)
    require_file(path, " (export DA3 with `davio export-da3`, XFeat with `davio export-xfeat`)")
    model = check_model_file(path)
    inputs, outputs = model_signature(model)
    names = {n for n, _, _ in inputs}
    where = str(path)
    info: dict = {"path": str(path), "size_bytes": path.stat().st_size}
    if "images" in names:
        h, w = check_da3_signature(inputs, outputs, where)
        info.update(contract="davio.da3", resolution=[h, w])
        views = dict((n, s) for n, _, s in inputs)["images"][1]
        if isinstance(views, int) and views > 0 and views != WINDOW_VIEWS:
            info["note"] = (f"exported for exactly {views} views: DAVIO calls DA3 on {WINDOW_VIEWS}-image "
                            f"windows, so `davio run` refuses it; {FIXED_VIEWS_HINT}")
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
    ops = {n.op_type for n in model.graph.node}
    if info["contract"] == "davio.da3" and "Softmax" in ops and "Attention" not in ops:
        # measured on an H100: 10.7 GiB for DA3-Base on 5 views against 3.7 GiB (BENCHMARKS.md, DA3 on a GPU)
        note = ("attention is spelled out in MatMul and Softmax (an opset-18 export): on a GPU it holds "
                "about three times the memory of an opset-23 export (davio export-da3's default); re-export "
                "it, or cap it with --gpu-mem-limit")
        info["note"] = f"{info['note']}; {note}" if "note" in info else note
    info["producer"] = f"{model.producer_name} {model.producer_version}".strip()
    info["metadata"] = {p.key: p.value for p in model.metadata_props}
    if info["contract"] == "davio.da3":
        info["precision"] = info["metadata"].get(PRECISION_KEY, "fp32")
        if info["precision"] == "fp16":
            # measured (BENCHMARKS.md, DA3 on a GPU): on an H200 0.56x the fp32 session time (Base, 5 views);
            # on 16 CPU cores 2.1x the fp32 time (Small)
            note = ("fp16 graph (backbone in float16, inputs and outputs float32): for the CUDA provider, "
                    "where its session took 0.46-0.63x the fp32 time (a whole call 0.57-0.76x); the CPU "
                    "provider runs it at about half the fp32 speed")
            info["note"] = f"{info['note']}; {note}" if "note" in info else note
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
