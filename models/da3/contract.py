"""The DA3 ONNX graph contract (DESIGN §4, notes/da3.md §4) and its validation.

One graph per checkpoint and resolution; B = 1, N (views) dynamic in [2, 8], H and W fixed
multiples of 14:

    inputs   images          f32  [1, N, 3, H, W]  RGB, ImageNet-normalised
             intrinsics      f32  [1, N, 3, 3]     pixels at H x W (only fx, fy are used)
             extrinsics      f32  [1, N, 4, 4]     w2c, normalised (view 0 = I)
             use_pose        bool [1]              false = unconditioned start-up call
    outputs  depth           f32  [1, N, H, W]     z-depth, normalised units
             conf            f32  [1, N, H, W]     >= 1
             pred_extrinsics f32  [1, N, 3, 4]     w2c, world = camera 0
             pred_intrinsics f32  [1, N, 3, 3]     at H x W

A signature is a list of `(name, type, shape)` with ONNX Runtime's type strings
('tensor(float)', 'tensor(bool)') and shapes whose entries are ints or symbolic names/None.
"""

from __future__ import annotations

from collections.abc import Sequence

from runtime.errors import ModelError

CONTRACT = "davio.da3"
CONTRACT_VERSION = 1
#: graph metadata key a DAVIO export writes: "fp32", or "fp16" (the backbone computes in float16; the
#: inputs and outputs are float32 all the same). Absent = fp32.
PRECISION_KEY = "davio.precision"
PATCH = 14
MIN_VIEWS, MAX_VIEWS = 2, 8
WINDOW_VIEWS = 5
"""Images per call of DAVIO's start-up and mapping windows (the paper's five; startup/mapping.window_images
defaults): a graph exported for a fixed other view count cannot serve them."""
FIXED_VIEWS_HINT = ("re-export it with a dynamic view count (`davio export-da3` does: one graph for 2..8 "
                    "views)")

F32, BOOL = "tensor(float)", "tensor(bool)"
# symbolic letters: N views, H/W the graph resolution; ints are fixed.
INPUTS = [
    ("images", F32, [1, "N", 3, "H", "W"]),
    ("intrinsics", F32, [1, "N", 3, 3]),
    ("extrinsics", F32, [1, "N", 4, 4]),
    ("use_pose", BOOL, [1]),
]
OUTPUTS = [
    ("depth", F32, [1, "N", "H", "W"]),
    ("conf", F32, [1, "N", "H", "W"]),
    ("pred_extrinsics", F32, [1, "N", 3, 4]),
    ("pred_intrinsics", F32, [1, "N", 3, 3]),
]

Signature = Sequence[tuple[str, str, Sequence[object]]]


def match_signature(
    actual: Signature, expected: Signature, kind: str, where: str, contract: str = "DA3"
) -> dict[str, object]:
    """Check `actual` against a contract signature; returns the bindings of its symbolic dims.

    Integer dims in `expected` must match exactly (a symbolic dim in the file is accepted for them);
    letters must be bound consistently: to one int, or left symbolic everywhere.

    Raises:
        ModelError: naming the file (`where`), the tensor and what differs.
    """
    by_name = {name: (typ, list(shape)) for name, typ, shape in actual}
    want = [n for n, _, _ in expected]
    missing = [n for n in want if n not in by_name]
    if missing:
        raise ModelError(
            f"{where}: not a {contract} graph: {kind} {missing} missing "
            f"(expected {want}, found {list(by_name)})"
        )
    extra = [n for n in by_name if n not in want]
    if extra:
        raise ModelError(f"{where}: unexpected {kind} {extra} (the contract has exactly {want})")
    bind: dict[str, object] = {}
    bound_by: dict[str, str] = {}      # the tensor that bound each letter first
    for name, typ, shape in expected:
        atyp, ashape = by_name[name]
        if atyp != typ:
            fp16 = (": a float16 graph at its edges; `davio export-da3 --precision fp16` keeps float32 "
                    "inputs and outputs around its float16 backbone" if atyp == "tensor(float16)" else "")
            raise ModelError(f"{where}: {kind[:-1]} '{name}' has type {atyp}, the contract needs {typ}{fp16}")
        if len(ashape) != len(shape):
            raise ModelError(
                f"{where}: {kind[:-1]} '{name}' has rank {len(ashape)} (shape {ashape}), "
                f"the contract needs rank {len(shape)} {shape}"
            )
        for i, (a, e) in enumerate(zip(ashape, shape, strict=False)):
            a_int = a if isinstance(a, int) and a > 0 else None
            if isinstance(e, int):
                if a_int is not None and a_int != e:
                    raise ModelError(
                        f"{where}: {kind[:-1]} '{name}' dim {i} is {a}, the contract needs {e} "
                        f"(shape {ashape} vs {shape})"
                    )
                continue
            value = a_int if a_int is not None else "?"
            if e in bind and bind[e] != value:
                def said(v: object) -> str:
                    return "dynamic" if v == "?" else str(v)
                raise ModelError(
                    f"{where}: {kind[:-1]} '{name}' dim {i} ({e}) is {said(value)} but {kind[:-1]} "
                    f"'{bound_by[e]}' has {said(bind[e])}: the contract's {e} must agree in every tensor"
                )
            bind[e] = value
            bound_by.setdefault(e, name)
    return bind


def check_da3_signature(inputs: Signature, outputs: Signature, where: str) -> tuple[int, int]:
    """Validate a graph's I/O against the DA3 contract; returns the graph resolution (H, W).

    Raises:
        ModelError: wrong names, types, ranks, inconsistent dims, dynamic or non-multiple-of-14 H/W.
    """
    b_in = match_signature(inputs, INPUTS, "inputs", where)
    b_out = match_signature(outputs, OUTPUTS, "outputs", where)
    for key in ("H", "W", "N"):
        a, b = b_in.get(key), b_out.get(key)
        if a != "?" and b != "?" and a != b:
            raise ModelError(f"{where}: {key} is {a} in the inputs but {b} in the outputs")
    H, W = b_in["H"], b_in["W"]
    if H == "?" or W == "?":
        raise ModelError(
            f"{where}: the DA3 graph must have a fixed resolution (got H={H}, W={W}); "
            "export one graph per resolution with `davio export-da3 --res HxW`"
        )
    if H % PATCH or W % PATCH:
        raise ModelError(f"{where}: graph resolution {H}x{W} is not a multiple of the {PATCH}-px patch")
    n = b_in["N"]
    if n != "?" and not MIN_VIEWS <= int(n) <= MAX_VIEWS:
        raise ModelError(f"{where}: graph has a fixed view count {n} outside [{MIN_VIEWS}, {MAX_VIEWS}]")
    return int(H), int(W)


def da3_resolution(width: int, height: int, long_side: int = 504) -> tuple[int, int]:
    """DA3's processing resolution (H, W) for a camera: long side to `long_side`, sides rounded to 14."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    s = long_side / max(width, height)
    h = max(PATCH, int(round(height * s / PATCH)) * PATCH)
    w = max(PATCH, int(round(width * s / PATCH)) * PATCH)
    return h, w
