"""Export DA3 to the DAVIO ONNX contract (models/da3/contract.py), check it against torch, write a card.

One graph per size and resolution, dynamo exporter, opset 23 (or 18), N views dynamic in [2, 8]. The
single-graph variant takes `use_pose`: cam_token = where(use_pose, cam_enc(K, E), learned tokens),
so use_pose=false is upstream's unconditioned forward with the first view as reference and
use_pose=true the pose-conditioned forward. The only change needed for the exporter (RoPE's
`int(positions.max())`) is applied at run time by a replacement `forward` computing the same
cos/sin from the positions directly.

DA3's position caches keep FakeTensors after an export, so `export_in_subprocess` runs every export
in a fresh Python process (`python -m tools.export.export_da3 REQUEST_JSON`).
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from models.da3.contract import CONTRACT, CONTRACT_VERSION, MAX_VIEWS, MIN_VIEWS, PATCH, PRECISION_KEY
from runtime.errors import ModelError
from runtime.files import sha256_file
from tools.export.da3_card import TOLERANCE, check_and_write_card
from tools.export.da3_check import INPUT_NAMES, OUTPUT_NAMES, check_inputs
from tools.export.graph_files import EXTERNAL_DATA_BYTES, move_into_place, remove_temporary, temporary_path

#: the default: attention as ONNX's own `Attention` and `RotaryEmbedding` operators (ONNX Runtime >= 1.23).
#: DA3-Base, 5 views: 3.7 GiB of an H100 instead of 10.7 GiB, 44 ms instead of 48; on 2 CPU cores, DA3-Small
#: at the same speed in half the memory (BENCHMARKS.md, "DA3 on a GPU")
OPSET = 23
#: opsets an export may ask for: 23, or 18 (attention spelled out in MatMul and Softmax) for older runtimes
OPSETS = (18, 23)


@dataclass
class ExportRequest:
    """What to export.

    Attributes:
        size: tiny | small | base | large | giant.
        height, width: graph resolution (multiples of 14).
        out: the .onnx path (the model card goes beside it, `.json`).
        checkpoint: DA3 weights (.safetensors or torch state dict), or None with random_init.
        random_init: random weights (tests, benchmarks); the card says so.
        seed: seed of the random weights and of the check inputs.
        check_views: N used for the torch-vs-ONNX Runtime check (2..8).
        tolerance: largest accepted relative error of any output in that check.
        opset: the ONNX opset of the graph (`OPSETS`).
        threads: torch / ORT threads during the export.
        precision: fp32, or fp16 (the backbone in float16, tools/export/fp16.py; checked on the CUDA
            provider where there is one). The fp32 graph is always checked first, at `TOLERANCE["fp32"]`.
    """

    size: str
    height: int
    width: int
    out: str
    checkpoint: str | None = None
    random_init: bool = False
    seed: int = 0
    check_views: int = 5
    tolerance: float | None = None
    threads: int = 2
    opset: int = OPSET
    precision: str = "fp32"

    def validate(self) -> None:
        if self.height % PATCH or self.width % PATCH or self.height <= 0 or self.width <= 0:
            raise ModelError(
                f"resolution {self.height}x{self.width}: both sides must be positive multiples of "
                f"{PATCH} (e.g. 378x504 for 4:3, 322x504 for EuRoC's 752x480)"
            )
        if (self.checkpoint is None) == (not self.random_init):
            raise ModelError("give exactly one of --checkpoint PATH or --random-init")
        if self.precision not in TOLERANCE:
            raise ModelError(f"precision {self.precision!r}: choose one of {', '.join(TOLERANCE)}")
        if self.opset not in OPSETS:
            raise ModelError(f"opset {self.opset}: the DA3 export offers {', '.join(map(str, OPSETS))}")
        if not MIN_VIEWS <= self.check_views <= MAX_VIEWS:
            raise ModelError(f"check views must be in [{MIN_VIEWS}, {MAX_VIEWS}], got {self.check_views}")


# ---------------------------------------------------------------------------------------------- torch side
def _rope_forward(self, tokens, positions):
    """2-D RoPE with cos/sin computed from the positions themselves (no data-dependent table size).

    Same maths and float32 operation order as the upstream module: each half of the features is
    rotated by angle position * base^(-2k/d) along its axis (y for the first half, x for the second).
    """
    import torch

    half = tokens.size(-1) // 2
    exponents = torch.arange(0, half, 2, device=tokens.device).float() / half
    inv_freq = 1.0 / (self.base_frequency**exponents)
    rotated = []
    for axis, feats in enumerate(tokens.chunk(2, dim=-1)):
        angles = positions[..., axis].to(inv_freq.dtype)[..., None] * inv_freq
        angles = torch.cat((angles, angles), dim=-1).to(tokens.dtype)
        cos, sin = angles.cos()[:, None], angles.sin()[:, None]
        swapped = torch.cat((-feats[..., half // 2 :], feats[..., : half // 2]), dim=-1)
        rotated.append(feats * cos + swapped * sin)
    return torch.cat(rotated, dim=-1)


def _positions(self, batch_size, height, width, device):
    """(batch, height*width, 2) integer (y, x) patch positions, row-major, built fresh (no cache)."""
    import torch

    ys = torch.arange(height, device=device)
    xs = torch.arange(width, device=device)
    grid = torch.stack(torch.meshgrid(ys, xs, indexing="ij"), dim=-1).reshape(1, height * width, 2)
    return grid.expand(batch_size, -1, -1).clone()


@contextlib.contextmanager
def rope_export_patch():
    """Temporarily replace upstream RoPE's forward with `_rope_forward` and its position getter with
    a cache-free `_positions` (cached tensors created while tracing leak FakeTensors)."""
    from depth_anything_3.model.dinov2.layers.rope import PositionGetter, RotaryPositionEmbedding2D

    originals = RotaryPositionEmbedding2D.forward, PositionGetter.__call__
    RotaryPositionEmbedding2D.forward, PositionGetter.__call__ = _rope_forward, _positions
    try:
        yield
    finally:
        RotaryPositionEmbedding2D.forward, PositionGetter.__call__ = originals


def _clear_caches(net) -> None:
    getter = getattr(net.backbone.pretrained, "position_getter", None)
    if getter is not None:
        getter.position_cache.clear()
    rope = getattr(net.backbone.pretrained, "rope", None)
    if rope is not None:
        rope.frequency_cache.clear()


def single_graph(net):
    """The contract's forward around a `DepthAnything3Net` (an nn.Module)."""
    import torch

    class SingleGraph(torch.nn.Module):
        def __init__(self, net) -> None:
            super().__init__()
            self.net = net

        def forward(self, images, intrinsics, extrinsics, use_pose):
            B, N = images.shape[0], images.shape[1]
            H, W = images.shape[-2], images.shape[-1]
            encoded = self.net.cam_enc(extrinsics, intrinsics, (H, W))
            learned = self.net.backbone.pretrained.camera_token
            learned = torch.cat([learned[:, :1].expand(B, 1, -1), learned[:, 1:].expand(B, N - 1, -1)], dim=1)
            cam_token = torch.where(use_pose.reshape(1, 1, 1), encoded, learned)
            feats, _ = self.net.backbone(images, cam_token=cam_token, export_feat_layers=[])
            out = self.net._process_depth_head(feats, H, W)
            out = self.net._process_camera_estimation(feats, H, W, out)
            return out.depth, out.depth_conf, out.extrinsics[..., :3, :], out.intrinsics

    return SingleGraph(net).eval()


def torch_reference(net, inputs: dict) -> dict:
    """Upstream eager forward (unpatched): unconditioned with the first view as reference, and
    conditioned on (K, E). Returns {mode: [depth, conf, w2c(3x4), K]} as numpy."""
    import torch

    x = torch.from_numpy(inputs["images"])
    K = torch.from_numpy(inputs["intrinsics"])
    E = torch.from_numpy(inputs["extrinsics"])
    refs = {}
    with torch.no_grad():
        for mode, kwargs in (
            ("uncond", {"ref_view_strategy": "first"}),
            ("cond", {"extrinsics": E, "intrinsics": K}),
        ):
            _clear_caches(net)
            o = net(x, **kwargs)
            refs[mode] = [
                o.depth.numpy(),
                o.depth_conf.numpy(),
                o.extrinsics[..., :3, :].numpy(),
                o.intrinsics.numpy(),
            ]
    _clear_caches(net)
    return refs


def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("torch", "onnx", "onnxscript", "onnxruntime", "depth-anything-3", "davio"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


def export_da3(req: ExportRequest) -> dict:
    """Export in this process (use `export_in_subprocess` unless this process is fresh); returns the card."""
    req.validate()
    import torch

    from tools.export.da3_net import LICENCES, build_net, load_checkpoint_, randomise_

    torch.set_num_threads(req.threads)
    torch.manual_seed(req.seed)
    t0 = time.perf_counter()
    net = build_net(req.size)
    if req.random_init:
        randomise_(net, req.seed)
        ckpt = {"checkpoint": "random-init", "seed": req.seed}
    else:
        ckpt = {"checkpoint": str(Path(req.checkpoint).resolve()), "sha256": sha256_file(req.checkpoint)}
        ckpt.update(load_checkpoint_(net, Path(req.checkpoint)))
    inputs = check_inputs(req.check_views, req.height, req.width, req.seed + 1)
    refs = torch_reference(net, inputs)
    out = Path(req.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    wrapper = single_graph(net)
    args = tuple(torch.from_numpy(inputs[k]) for k in INPUT_NAMES[:3]) + (torch.tensor([True]),)
    n = torch.export.Dim("N", min=MIN_VIEWS, max=MAX_VIEWS)
    dyn = {"images": {1: n}, "intrinsics": {1: n}, "extrinsics": {1: n}, "use_pose": None}
    t1 = time.perf_counter()
    with rope_export_patch(), torch.no_grad():
        _clear_caches(net)
        program = torch.onnx.export(
            wrapper,
            args,
            dynamo=True,
            opset_version=req.opset,
            input_names=INPUT_NAMES,
            output_names=OUTPUT_NAMES,
            dynamic_shapes=dyn,
            verbose=False,
        )
    _clear_caches(net)
    meta = {
        "davio.contract": CONTRACT,
        "davio.contract_version": str(CONTRACT_VERSION),
        "davio.size": req.size,
        "davio.resolution": f"{req.height}x{req.width}",
        "davio.checkpoint": ckpt["checkpoint"],
        PRECISION_KEY: "fp32",
    }
    program.model.metadata_props.update(meta)
    n_params = sum(p.numel() for p in net.parameters())
    remove_temporary(out)   # a left-over data file would be appended to
    try:
        program.save(str(temporary_path(out)), external_data=n_params * 4 > EXTERNAL_DATA_BYTES)
        move_into_place(temporary_path(out), out)   # the exporter names the data after its file
    except BaseException:
        remove_temporary(out)
        raise
    export_s = time.perf_counter() - t1
    card = {
        "contract": CONTRACT,
        "contract_version": CONTRACT_VERSION,
        "model": "Depth Anything 3",
        "size": req.size,
        "resolution": [req.height, req.width],
        "views": [MIN_VIEWS, MAX_VIEWS],
        "opset": req.opset,
        "precision": req.precision,
        "licence": LICENCES[req.size] if not req.random_init else "none (random weights)",
        "licence_note": "DA3 code is Apache-2.0 (ByteDance); checkpoint licence as given by its release",
        **ckpt,
        "parameters": n_params,
        "file": out.name,
        "export_versions": _versions(),
        "export_seconds": round(export_s, 2),
        "total_seconds": None,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    return check_and_write_card(out, inputs, refs, req, card, started=t0)


def export_in_subprocess(req: ExportRequest, timeout_s: float | None = None) -> dict:
    """Run `export_da3` in a fresh Python process (DA3's caches keep FakeTensors after an export).

    The child's stdout carries only its JSON result; its stderr is captured and its last line is
    quoted when it fails. Relative paths are resolved against this process's working directory.
    Returns the model card.

    Raises:
        ModelError: with the child's error message when the export or its check fails.
    """
    req.validate()
    req = replace(
        req,
        out=str(Path(req.out).resolve()),
        checkpoint=None if req.checkpoint is None else str(Path(req.checkpoint).resolve()),
    )
    repo = Path(__file__).resolve().parents[2]
    env = dict(os.environ)
    env["PYTHONPATH"] = str(repo) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("DA3_LOG_LEVEL", "WARN")  # upstream's logger prints INFO lines on stdout
    cmd = [sys.executable, "-m", "tools.export.export_da3", json.dumps(asdict(req))]
    proc = subprocess.run(cmd, cwd=repo, env=env, capture_output=True, text=True, timeout=timeout_s)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    result = json.loads(lines[-1]) if lines else {}
    if proc.returncode != 0 or "error" in result or not lines:
        msg = result.get("error") or proc.stderr.strip().splitlines()[-1:] or ["unknown error"]
        raise ModelError(f"DA3 export failed: {msg if isinstance(msg, str) else msg[0]}")
    return result


def _worker(argv: list[str]) -> int:
    import logging
    import warnings

    warnings.filterwarnings("ignore")
    logging.disable(logging.WARNING)
    req = ExportRequest(**json.loads(argv[0]))
    try:
        card = export_da3(req)
    except ModelError as exc:
        print(json.dumps({"error": str(exc)}))
        return 1
    print(json.dumps(card))
    return 0


if __name__ == "__main__":
    sys.exit(_worker(sys.argv[1:]))
