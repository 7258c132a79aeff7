"""The model card of an exported DA3 graph: its checks against torch (the fp32 graph on the CPU provider,
the fp16 rewrite on the best provider here and against the fp32 graph), hashes and data file; written
beside the graph (`<graph>.json`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

from runtime.errors import ModelError
from runtime.files import sha256_file
from runtime.json_out import strict_dumps
from tools.export.da3_check import compare_with_onnxruntime, output_errors, run_graph, worst_error
from tools.export.graph_files import data_path, remove_graph, save_graph

if TYPE_CHECKING:
    from tools.export.export_da3 import ExportRequest

#: the check's default tolerance (largest error against torch, relative to the output's largest value).
#: fp16 is checked on the CUDA provider, whose TF32 alone put random-weight DA3-Base up to 3.7 % of the
#: depth range away from the CPU (BENCHMARKS.md, "DA3 on a GPU"): its check catches a broken rewrite
#: (non-finite values, errors of order one); the errors themselves are in the model card.
TOLERANCE = {"fp32": 1e-3, "fp16": 1e-1}
#: the fp16 graph against the fp32 graph on the same provider (same TF32, same kernels but the region's):
#: on an H200 they agreed within 3.9e-3 of an output's largest value (BENCHMARKS.md, "fp16 backbone")
FP16_VS_FP32 = 1e-2


def check_and_write_card(out: Path, inputs: dict, refs: dict, req: ExportRequest, card: dict,
                         started: float | None = None) -> dict:
    """Check the fp32 graph at `out` against `refs` (torch's outputs) on the CPU provider, make and check
    its fp16 rewrite under `req.precision` fp16, and write `card` (completed with the checks, hashes, data
    file and, from `started` (a time.perf_counter()), total_seconds) beside `out`; returns the card.

    Raises:
        ModelError: a check failed. A failed fp32 graph is kept for inspection under `--precision fp32`;
            under fp16 it is removed (no fp32 graph under the name asked for an fp16 one), the card stays.
    """
    # --tolerance is the fp16 graph's under --precision fp16; the fp32 graph before it is held to 1e-3
    fp32_tolerance = TOLERANCE["fp32"]
    if req.precision == "fp32" and req.tolerance is not None:
        fp32_tolerance = req.tolerance
    errors, provider = compare_with_onnxruntime(out, inputs, refs, req.threads)
    check = check_record(req, provider, errors, fp32_tolerance)
    card = dict(card, sha256=sha256_file(out), **_data_file(out), check=check)
    fp32_ok = check["max_rel_error"] <= fp32_tolerance
    if not fp32_ok and req.precision == "fp16":
        remove_graph(out)
        _drop_data_file(card)
        card.update(file=None, sha256=None, removed="the fp32 graph failed its check: no fp16 rewrite made")
    elif req.precision == "fp16":
        card["fp32_check"] = check
        card["fp16"], card["check"] = fp16_rewrite_and_check(out, inputs, refs, req)
        _drop_data_file(card)       # the fp32 graph's; the fp16 graph may keep its weights in itself
        card.update(sha256=sha256_file(out), **_data_file(out))
    if started is not None:
        card["total_seconds"] = round(time.perf_counter() - started, 2)
    out.with_suffix(".json").write_text(strict_dumps(card, indent=2) + "\n")
    worst, tolerance = card["check"]["max_rel_error"], card["check"]["tolerance"]
    if not fp32_ok or not worst <= tolerance:
        which = "the fp32 graph" if not fp32_ok or req.precision == "fp32" else "the fp16 graph"
        removed = " (removed: no fp16 rewrite was made)" if card["file"] is None else ""
        raise ModelError(
            f"{out}: ONNX Runtime ({card['check']['provider']}) disagrees with torch on {which}{removed} "
            f"(max relative error {worst:.3g} > {tolerance:g}); see {out.with_suffix('.json')}"
        )
    vs_fp32 = card["check"].get("vs_fp32")
    if vs_fp32 is not None and not vs_fp32["max_rel_error"] <= vs_fp32["tolerance"]:
        raise ModelError(
            f"{out}: the fp16 graph differs from the fp32 graph on {card['check']['provider']} by "
            f"{vs_fp32['max_rel_error']:.3g} of an output's largest value (> {vs_fp32['tolerance']:g}); "
            f"see {out.with_suffix('.json')}; the fp32 graph (--precision fp32) is unaffected"
        )
    return card


def check_record(req: ExportRequest, provider: str, errors: dict, tolerance: float) -> dict:
    """The card's record of one check: its inputs (views, seed), the provider that ran, the errors
    (da3_check.output_errors), the worst of them and the tolerance it is held to."""
    return {"views": req.check_views, "seed": req.seed + 1, "provider": provider, "errors": errors,
            "max_rel_error": worst_error(errors), "tolerance": tolerance}


def fp16_rewrite_and_check(out: Path, inputs: dict, refs: dict, req: ExportRequest) -> tuple[dict, dict]:
    """Rewrite the checked fp32 graph at `out` with its backbone in fp16 (tools/export/fp16.py) and check
    it on the best provider here (CUDA where available) against torch and against the fp32 graph on the
    same provider. Returns (summary, check); the check names the providers that actually ran.

    Raises:
        ModelError: the rewrite, or the rewritten graph's session or run, failed; `out`, its data file and
            its card are removed then (the file would hold an fp32 or a broken graph under the fp16 name).
    """
    import onnx

    from models.providers import choose_providers
    from tools.export.fp16 import to_mixed_fp16

    providers, _ = choose_providers()
    provider = providers[0]
    try:
        fp32_outputs, fp32_provider = run_graph(out, inputs, req.threads, providers)
        provider = fp32_provider      # what ONNX Runtime ran (it falls back to the CPU)
        model, summary = to_mixed_fp16(onnx.load(str(out)), where=str(out))
        save_graph(model, out)        # its weights in `<out>.data` when they exceed one protobuf
        got, provider = run_graph(out, inputs, req.threads, providers)
    except Exception as exc:
        remove_graph(out)
        raise ModelError(
            f"{out}: the fp16 rewrite failed on {provider} ({type(exc).__name__}: {str(exc)[:300]}); "
            "nothing was written: the fp32 graph (--precision fp32) is unaffected"
        ) from exc
    tolerance = req.tolerance if req.tolerance is not None else TOLERANCE["fp16"]
    check = check_record(req, provider, output_errors(got, refs, out), tolerance)
    vs_fp32 = output_errors(got, fp32_outputs, out)
    check["vs_fp32"] = {"errors": vs_fp32, "max_rel_error": worst_error(vs_fp32), "tolerance": FP16_VS_FP32,
                        "fp32_provider": fp32_provider}
    return summary, check


def _data_file(out: Path) -> dict:
    """The card's entries for the graph's external data file (graphs over 2 GiB), none without one."""
    data = data_path(out)
    return {"data_file": data.name, "data_sha256": sha256_file(data)} if data.exists() else {}


def _drop_data_file(card: dict) -> None:
    for key in ("data_file", "data_sha256"):
        card.pop(key, None)
