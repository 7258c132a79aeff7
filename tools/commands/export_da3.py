"""`davio export-da3`: export a DA3 checkpoint to the DAVIO ONNX contract (needs the `export` extra)."""

from __future__ import annotations

import argparse
from pathlib import Path

from runtime.json_out import strict_dumps
from tools.cli_types import count, number

NAME = "export-da3"
HELP = "export a Depth Anything 3 checkpoint to ONNX (one graph per size and resolution)"
DESCRIPTION = (
    "Export Depth Anything 3 to the DAVIO ONNX contract: opset 23, fixed HxW, 2..8 views, one graph that "
    "serves both the start-up call and the pose-conditioned call. ONNX Runtime is checked against torch "
    "on random inputs and a model card (.json) is written beside the graph. Needs the export extra: "
    "pip install -e '.[export]' && pip install --no-deps depth-anything-3. Small and Base checkpoints "
    "are Apache-2.0; Large and Giant are CC BY-NC 4.0."
)


def parse_resolution(text: str) -> tuple[int, int]:
    """'378x504' -> (378, 504) (height x width)."""
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"resolution must look like 378x504 (HxW), got {text!r}") from exc
    return h, w


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument(
        "--checkpoint",
        metavar="PATH",
        help="DA3 weights: model.safetensors (HF release), or a torch .pt/.pth/.bin state dict (read with "
        "weights_only=True, and only on torch >= 2.10: older releases have weights_only bypasses)",
    )
    src.add_argument("--random-init", action="store_true", help="random weights (tests and benchmarks only)")
    p.add_argument(
        "--size",
        default="small",
        choices=["tiny", "small", "base", "large", "giant"],
        help="DA3 size (must match the checkpoint); tiny = width 64, 4 blocks, for tests",
    )
    p.add_argument(
        "--res",
        default="378x504",
        type=parse_resolution,
        help="graph resolution HxW, multiples of 14 (322x504 fits EuRoC's 752x480)",
    )
    p.add_argument(
        "--out", metavar="PATH", default=None, help="output .onnx (default da3_SIZE_HxW.onnx here)"
    )
    p.add_argument("--seed", type=count(0), default=0, help="seed of random weights and check inputs")
    p.add_argument("--check-views", type=count(2, 8), default=5,
                   help="views N of the torch vs ONNX Runtime check (2-8)")
    p.add_argument(
        "--tolerance",
        type=number,
        default=None,
        help="largest accepted error against torch, relative to each output's largest value (default 1e-3; "
        "with --precision fp16 it is the fp16 graph's, default 0.1, and the fp32 graph is still held to "
        "1e-3; the fp16 graph must also agree with the fp32 one within 1e-2)",
    )
    p.add_argument(
        "--precision",
        default="fp32",
        choices=["fp32", "fp16"],
        help="fp16: the ViT backbone in float16, the heads and camera encoder/decoder in float32 (as "
        "upstream's autocast), inputs and outputs float32; for GPUs (half the weights; BENCHMARKS.md, "
        "'DA3 on a GPU'). The fp32 graph is checked first, the fp16 one on the CUDA provider where "
        "there is one",
    )
    p.add_argument("--threads", type=count(1), default=2, help="torch / ONNX Runtime threads")
    p.add_argument(
        "--opset",
        type=int,
        default=23,
        choices=[18, 23],
        help="ONNX opset (default 23): 23 writes attention as ONNX's own Attention operator (ONNX Runtime "
        ">= 1.23), which held a third of the GPU memory of 18 and ran a few %% faster (BENCHMARKS.md); 18 "
        "spells it out in MatMul and Softmax, for older runtimes",
    )
    p.add_argument("--json", action="store_true", help="print the model card as JSON")


def run(args: argparse.Namespace) -> int:
    from runtime.errors import ConfigError
    from tools.export.requirements import require

    if args.checkpoint and not Path(args.checkpoint).is_file():
        raise ConfigError(f"--checkpoint {args.checkpoint}: no such file")
    require("the DA3 export", ("depth_anything_3", "depth-anything-3"), ("onnxscript", "onnxscript"),
            ("einops", "einops"), ("omegaconf", "omegaconf"), ("addict", "addict"),
            ("safetensors", "safetensors"))
    from tools.export.export_da3 import ExportRequest, export_in_subprocess

    h, w = args.res
    suffix = "_fp16" if args.precision == "fp16" else ""
    out = args.out or f"da3_{args.size}_{h}x{w}{suffix}.onnx"
    req = ExportRequest(
        size=args.size,
        height=h,
        width=w,
        out=out,
        checkpoint=args.checkpoint,
        random_init=args.random_init,
        seed=args.seed,
        check_views=args.check_views,
        tolerance=args.tolerance,
        threads=args.threads,
        opset=args.opset,
        precision=args.precision,
    )
    card = export_in_subprocess(req)
    if args.json:
        print(strict_dumps(card, indent=2))
        return 0
    print(
        f"wrote {out} ({card['parameters'] / 1e6:.1f}M parameters, "
        f"{card['resolution'][0]}x{card['resolution'][1]}, "
        f"opset {card['opset']}, {card['precision']}, licence: {card['licence']})"
    )
    if card.get("data_file"):
        print(f"its weights are in {card['data_file']} beside it (too large for one ONNX file): "
              "keep the two together")
    if "fp32_check" in card:
        fp16 = card["fp16"]
        print(f"fp32 graph: ONNX Runtime vs torch, max relative error "
              f"{card['fp32_check']['max_rel_error']:.2e}; {fp16['fp16_nodes']} of "
              f"{fp16['fp16_nodes'] + fp16['fp32_nodes']} nodes now in fp16")
    print(
        f"ONNX Runtime ({card['check']['provider']}) vs torch on {card['check']['views']} views: max "
        f"relative error {card['check']['max_rel_error']:.2e} (tolerance {card['check']['tolerance']:g})"
    )
    for key, e in card["check"]["errors"].items():
        print(f"  {key:<24} max abs {e['max_abs']:.2e}  max rel {e['max_rel']:.2e}")
    print(f"model card: {Path(out).with_suffix('.json')}; check it with: davio info --model {out}")
    return 0
