"""The XFeat backbone ONNX contract (notes/matcher.md §2) and its validation.

input   image        f32 [1, 1, H, W]      grey in [0, 1], H and W multiples of 8 (dynamic)
outputs feats        f32 [1, 64, H/8, W/8] L2-normalised dense descriptors
        kpt_logits   f32 [1, 65, H/8, W/8] 8x8 cell logits + one "no keypoint" bin
        reliability  f32 [1, 1, H/8, W/8]  descriptor reliability in [0, 1]
"""

from __future__ import annotations

from models.da3.contract import F32, Signature, match_signature

CONTRACT = "davio.xfeat_backbone"
CONTRACT_VERSION = 1
CELL = 8
DESC_DIM = 64

INPUTS = [("image", F32, [1, 1, "H", "W"])]
OUTPUTS = [
    ("feats", F32, [1, DESC_DIM, "h", "w"]),
    ("kpt_logits", F32, [1, CELL * CELL + 1, "h", "w"]),
    ("reliability", F32, [1, 1, "h", "w"]),
]


def check_xfeat_signature(inputs: Signature, outputs: Signature, where: str) -> None:
    """Validate a graph's I/O against the XFeat backbone contract.

    Raises:
        ModelError: wrong names, types, ranks or channel counts, or inconsistent output grids.
    """
    match_signature(inputs, INPUTS, "inputs", where, contract="XFeat")
    match_signature(outputs, OUTPUTS, "outputs", where, contract="XFeat")


LIGHTERGLUE_CONTRACT = "davio.lighterglue"
LIGHTERGLUE_VERSION = 1
LIGHTERGLUE_INPUTS = [
    ("kpts0", F32, [1, "M", 2]),
    ("kpts1", F32, [1, "N", 2]),
    ("desc0", F32, [1, "M", DESC_DIM]),
    ("desc1", F32, [1, "N", DESC_DIM]),
]
LIGHTERGLUE_OUTPUTS = [("log_assignment", F32, [1, "M1", "N1"])]


def check_lighterglue_signature(inputs: Signature, outputs: Signature, where: str) -> None:
    """Validate a graph's I/O against the LighterGlue contract (kpts/desc pairs -> log assignment).

    Raises:
        ModelError: wrong names, types, ranks or descriptor size.
    """
    match_signature(inputs, LIGHTERGLUE_INPUTS, "inputs", where, contract="LighterGlue")
    match_signature(outputs, LIGHTERGLUE_OUTPUTS, "outputs", where, contract="LighterGlue")
