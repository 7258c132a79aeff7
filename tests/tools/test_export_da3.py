"""DA3 export: RoPE patch identity, checkpoint loading, and a tiny real-architecture export end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runtime.errors import ModelError
from tools.export.export_da3 import ExportRequest


def _need_export_deps():
    pytest.importorskip("torch", reason="needs the export extra (torch)")
    pytest.importorskip("depth_anything_3.model.da3", reason="needs depth-anything-3 (pip install --no-deps)")


def test_request_validation():
    with pytest.raises(ModelError, match="multiples of 14"):
        ExportRequest("small", 380, 504, "x.onnx", random_init=True).validate()
    with pytest.raises(ModelError, match="exactly one"):
        ExportRequest("small", 378, 504, "x.onnx").validate()
    with pytest.raises(ModelError, match="exactly one"):
        ExportRequest("small", 378, 504, "x.onnx", checkpoint="w.safetensors", random_init=True).validate()
    with pytest.raises(ModelError, match="opset 17: the DA3 export offers 18, 23"):
        ExportRequest("small", 378, 504, "x.onnx", random_init=True, opset=17).validate()
    with pytest.raises(ModelError, match="precision 'fp8': choose one of fp32, fp16"):
        ExportRequest("small", 378, 504, "x.onnx", random_init=True, precision="fp8").validate()


@pytest.mark.export
def test_rope_patch_is_identical_to_upstream():
    _need_export_deps()
    import torch
    from depth_anything_3.model.dinov2.layers.rope import PositionGetter, RotaryPositionEmbedding2D

    from tools.export.export_da3 import rope_export_patch

    rope = RotaryPositionEmbedding2D(frequency=100.0)
    tokens = torch.randn(3, 2, 1 + 6 * 9, 32)
    pos = PositionGetter()(3, 6, 9, device="cpu") + 1
    pos = torch.cat([torch.zeros(3, 1, 2, dtype=pos.dtype), pos], dim=1)
    ref = rope(tokens, pos)
    with rope_export_patch():
        got = rope(tokens, pos)
        pos_patched = PositionGetter()(3, 6, 9, device="cpu")
    assert torch.equal(got, ref)
    assert torch.equal(pos_patched + 1, pos[:, 1:])


@pytest.mark.export
def test_checkpoint_loading_strips_prefix_and_rejects_other_sizes(tmp_path):
    _need_export_deps()
    import torch
    from safetensors.torch import save_file

    from tools.export.da3_net import build_net, load_checkpoint_, randomise_

    src = build_net("tiny")
    randomise_(src, 7)
    sd = {f"model.{k}": v.detach().clone().contiguous() for k, v in src.state_dict().items()}
    save_file(sd, str(tmp_path / "model.safetensors"))
    dst = build_net("tiny")
    info = load_checkpoint_(dst, tmp_path / "model.safetensors")
    assert info["prefix"] == "model." and info["keys"] == len(sd)
    for (k, a), (_, b) in zip(src.state_dict().items(), dst.state_dict().items(), strict=True):
        assert torch.equal(a, b), k
    torch.save(
        {"state_dict": {k: v[..., :1] if v.ndim else v for k, v in src.state_dict().items()}},
        tmp_path / "bad.pt",
    )
    with pytest.raises(ModelError, match="shapes do not match"):
        load_checkpoint_(build_net("tiny"), tmp_path / "bad.pt")
    save_file({"other.weight": torch.zeros(2)}, str(tmp_path / "other.safetensors"))
    with pytest.raises(ModelError, match="missing keys"):
        load_checkpoint_(build_net("tiny"), tmp_path / "other.safetensors")
    with pytest.raises(ModelError, match="not found"):
        load_checkpoint_(build_net("tiny"), tmp_path / "absent.safetensors")


@pytest.mark.export
@pytest.mark.slow
def test_tiny_export_agrees_with_torch_and_runs_in_the_runtime(tmp_path, capsys, monkeypatch):
    _need_export_deps()
    import onnx

    from calib import Pinhole
    from models.da3 import OnnxDA3
    from models.inspect_model import inspect_model
    from runtime.events import Frame
    from tools.cli import main

    out = tmp_path / "da3_tiny_28x42.onnx"
    monkeypatch.chdir(tmp_path)  # a relative --out is relative to the caller, not to the export child
    rc = main(
        ["export-da3", "--random-init", "--size", "tiny", "--res", "28x42", "--out", out.name, "--json"]
    )
    assert rc == 0
    card = json.loads(capsys.readouterr().out)
    # ONNX Runtime against the unpatched eager torch model, both calls, all four outputs
    assert set(card["check"]["errors"]) == {
        f"{m}.{o}"
        for m in ("uncond", "cond")
        for o in ("depth", "conf", "pred_extrinsics", "pred_intrinsics")
    }
    assert card["check"]["max_rel_error"] < 1e-4
    assert card["checkpoint"] == "random-init" and card["resolution"] == [28, 42] and card["opset"] == 23
    ops = [n.op_type for n in onnx.load(out).graph.node]
    assert ops.count("Attention") >= 4 and "Softmax" not in ops  # ONNX's own attention operator
    info = inspect_model(out)
    assert info["contract"] == "davio.da3" and info["resolution"] == [28, 42]
    assert (
        info["metadata"]["davio.contract"] == "davio.da3" and info["model_card"]["sha256"] == card["sha256"]
    )
    cam = Pinhole(84, 56, 60.0, 60.0, 41.5, 27.5)
    model = OnnxDA3(out, cam, threads=1)
    rng = np.random.default_rng(0)
    frames = [Frame(i, rng.integers(0, 255, (56, 84), dtype=np.uint8)) for i in range(4)]
    pred = model.predict(frames)
    assert pred.depth.shape == (4, 56, 84) and np.isfinite(pred.depth).all() and (pred.depth > 0).all()
    assert (pred.conf >= 1).all()
    T_CW = np.tile(np.eye(4), (4, 1, 1))
    T_CW[:, 0, 3] = [0.0, -0.1, -0.2, -0.3]
    pred = model.predict(frames, np.tile(cam.K, (4, 1, 1)), T_CW)
    assert np.isfinite(pred.scale) and pred.scale > 0 and np.isfinite(pred.depth).all()


@pytest.mark.export
@pytest.mark.slow
def test_opset_18_export_spells_attention_out_and_agrees_with_torch(tmp_path, capsys, monkeypatch):
    _need_export_deps()
    import onnx

    from tools.cli import main

    monkeypatch.chdir(tmp_path)
    rc = main(["export-da3", "--random-init", "--size", "tiny", "--res", "28x42", "--opset", "18",
               "--out", "da3_tiny_op18.onnx", "--json"])
    assert rc == 0
    card = json.loads(capsys.readouterr().out)
    assert card["opset"] == 18 and card["check"]["max_rel_error"] < 1e-4
    graph = onnx.load(tmp_path / "da3_tiny_op18.onnx")
    ops = [n.op_type for n in graph.graph.node]
    # the tiny net's 4 blocks + the camera decoder attend, as MatMul-Softmax chains in opset 18
    assert "Attention" not in ops and ops.count("Softmax") >= 4
    assert {o.version for o in graph.opset_import if o.domain in ("", "ai.onnx")} == {18}


@pytest.mark.export
@pytest.mark.slow
def test_fp16_export_puts_the_backbone_in_fp16_and_agrees_with_torch(tmp_path, capsys, monkeypatch):
    _need_export_deps()
    import onnx

    from calib import Pinhole
    from models.da3 import OnnxDA3
    from runtime.events import Frame
    from tools.cli import main
    from tools.export.fp16 import in_scope

    monkeypatch.chdir(tmp_path)
    rc = main(["export-da3", "--random-init", "--size", "tiny", "--res", "28x42", "--precision", "fp16",
               "--json"])
    assert rc == 0
    card = json.loads(capsys.readouterr().out)
    out = tmp_path / "da3_tiny_28x42_fp16.onnx"
    assert card["precision"] == "fp16" and card["file"] == out.name
    assert card["fp32_check"]["max_rel_error"] < 1e-4   # the graph before the rewrite
    assert card["check"]["max_rel_error"] < 5e-2 and card["check"]["tolerance"] == 0.1
    assert card["fp16"]["fp16_nodes"] > 100 and card["fp16"]["fp32_nodes"] > 100
    graph = onnx.load(out)
    meta = {p.key: p.value for p in graph.metadata_props}
    assert meta["davio.precision"] == "fp16"
    # every backbone weight matrix is fp16, every head and camera-decoder weight fp32
    f16 = {t.name for t in graph.graph.initializer if t.data_type == onnx.TensorProto.FLOAT16}
    consumers = {}
    for n in graph.graph.node:
        for name in n.input:
            consumers.setdefault(name, []).append(n)
    mats = [n for n in graph.graph.node if n.op_type in ("MatMul", "Gemm", "Conv") and len(n.input) > 1]
    assert mats
    for n in mats:
        weight_is_f16 = n.input[1] in f16 or n.input[1].endswith("__to_fp16")
        assert weight_is_f16 == in_scope(n, "net.backbone"), (n.name, n.input[1])
    # the depth head's exp (depth, confidence) reads a float32 tensor made by a head node
    producers = {o: n for n in graph.graph.node for o in n.output}
    head_exps = [n for n in graph.graph.node if n.op_type == "Exp" and in_scope(n, "net.head")]
    assert head_exps
    for n in head_exps:
        src = producers.get(n.input[0])
        assert src is not None and in_scope(src, "net.head") and src.op_type != "Cast", (n.name, n.input[0])
    cam = Pinhole(84, 56, 60.0, 60.0, 41.5, 27.5)
    model = OnnxDA3(out, cam, threads=1)
    rng = np.random.default_rng(0)
    frames = [Frame(i, rng.integers(0, 255, (56, 84), dtype=np.uint8)) for i in range(4)]
    pred = model.predict(frames)
    assert np.isfinite(pred.depth).all() and (pred.depth > 0).all() and (pred.conf >= 1).all()
