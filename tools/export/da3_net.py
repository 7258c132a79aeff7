"""Build DA3's `DepthAnything3Net` from the PyPI package `depth-anything-3` for export (torch only).

The package is installed without its dependencies (torch, einops, omegaconf, addict suffice); we
import its model classes and configs and never copy its code. Sizes: the upstream configs
(small, base, large, giant) and `tiny`, the same classes at width 64 with 4 blocks, for tests.
"""

from __future__ import annotations

from pathlib import Path

from runtime.errors import ModelError
from tools.export.checkpoint import read_state_dict

#: checkpoint licences (DA3 README): only Small and Base are Apache-2.0 and pose-conditionable.
LICENCES = {
    "small": "Apache-2.0",
    "base": "Apache-2.0",
    "large": "CC-BY-NC-4.0",
    "giant": "CC-BY-NC-4.0",
    "tiny": "none (test model, random weights)",
}
SIZES = tuple(LICENCES)
#: the upstream config of each size
CONFIGS = {
    "small": "da3-small.yaml",
    "base": "da3-base.yaml",
    "large": "da3-large.yaml",
    "giant": "da3-giant.yaml",
}


def import_da3():
    """Import the package, or raise ModelError saying how to install it."""
    try:
        import depth_anything_3  # noqa: F401
        import torch  # noqa: F401
        from depth_anything_3.model.da3 import DepthAnything3Net  # noqa: F401
    except ImportError as exc:
        raise ModelError(
            f"the DA3 export needs torch and depth-anything-3 ({exc}); install with "
            "`pip install -e '.[export]' && pip install --no-deps depth-anything-3`"
        ) from exc


def _tiny_net():
    """DA3 architecture at width 64, 4 blocks (alternating attention from block 2), random weights."""
    import torch.nn as nn
    from depth_anything_3.model.cam_dec import CameraDec
    from depth_anything_3.model.cam_enc import CameraEnc
    from depth_anything_3.model.da3 import DepthAnything3Net
    from depth_anything_3.model.dinov2.vision_transformer import DinoVisionTransformer
    from depth_anything_3.model.dualdpt import DualDPT

    class TinyDinoV2(nn.Module):
        """Holds the ViT as `.pretrained` and calls it like upstream's DinoV2 wrapper."""

        def __init__(self) -> None:
            super().__init__()
            self.out_layers = [0, 1, 2, 3]
            self.pretrained = DinoVisionTransformer(
                img_size=518,
                patch_size=14,
                embed_dim=64,
                depth=4,
                num_heads=2,
                mlp_ratio=4,
                alt_start=2,
                qknorm_start=2,
                rope_start=2,
                cat_token=True,
            )

        def forward(self, x, **kwargs):
            return self.pretrained.get_intermediate_layers(x, self.out_layers, **kwargs)

    head = DualDPT(dim_in=128, output_dim=2, features=16, out_channels=[8, 16, 32, 64])
    return DepthAnything3Net(
        TinyDinoV2(),
        head,
        cam_dec=CameraDec(dim_in=128),
        cam_enc=CameraEnc(dim_out=64, trunk_depth=1, num_heads=2),
    )


def build_net(size: str):
    """An eval-mode `DepthAnything3Net` of `size` (weights as constructed: mostly zeros/defaults)."""
    import_da3()
    if size not in SIZES:
        raise ModelError(f"unknown DA3 size {size!r}; choose one of {', '.join(SIZES)}")
    if size == "tiny":
        net = _tiny_net()
    else:
        import depth_anything_3
        from depth_anything_3.cfg import create_object, load_config

        cfg = load_config(str(Path(list(depth_anything_3.__path__)[0]) / "configs" / CONFIGS[size]))
        for key in ("gs_head", "gs_adapter"):  # the 3DGS branch is not part of the depth contract
            if key in cfg:
                cfg.pop(key)
        net = create_object(cfg)
    return net.eval()


def randomise_(net, seed: int) -> None:
    """Give parameters that are constructed as all-zero (tokens, pos-embed, ...) N(0, 0.02) values."""
    import torch

    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            if not p.any():
                p.copy_(torch.randn(p.shape, generator=g) * 0.02)


def load_checkpoint_(net, path: Path) -> dict:
    """Load DA3 weights (.safetensors, or a torch .pt/.pth/.bin state dict) into `net` strictly.

    The file is read by `tools.export.checkpoint.read_state_dict` (torch pickles only on a torch
    without known `weights_only` bypasses). HF checkpoints prefix keys with `model.` (the API class
    wraps the net); the prefix is stripped. Keys of the 3DGS branch are ignored.
    Returns {'keys': n, 'ignored': [...], 'prefix': str}.

    Raises:
        ModelError: unreadable or refused file, missing or unexpected keys, or shapes of another size.
    """
    path = Path(path)
    sd = read_state_dict(path)
    for wrapper_key in ("state_dict", "model"):
        if isinstance(sd, dict) and isinstance(sd.get(wrapper_key), dict):
            sd = sd[wrapper_key]
    if not isinstance(sd, dict) or not sd:
        raise ModelError(f"{path}: checkpoint holds no state dict")
    prefix = ""
    own = set(net.state_dict())
    for cand in ("model.", "module.", "model.module."):
        if sum(k.startswith(cand) for k in sd) > len(sd) // 2 and not any(k.startswith(cand) for k in own):
            prefix = cand
    if prefix:
        sd = {k[len(prefix) :] if k.startswith(prefix) else k: v for k, v in sd.items()}
    ignored = sorted(k for k in sd if k.startswith(("gs_head.", "gs_adapter.")))
    sd = {k: v for k, v in sd.items() if k not in ignored}
    missing, unexpected = sorted(own - set(sd)), sorted(set(sd) - own)
    if missing or unexpected:
        raise ModelError(
            f"{path}: checkpoint does not match this DA3 size: {len(missing)} missing keys "
            f"{missing[:3]}, {len(unexpected)} unexpected keys {unexpected[:3]}"
        )
    try:
        net.load_state_dict(sd, strict=True)
    except RuntimeError as exc:
        raise ModelError(f"{path}: checkpoint shapes do not match this DA3 size ({str(exc)[:300]})") from exc
    return {"keys": len(sd), "ignored": ignored, "prefix": prefix}
