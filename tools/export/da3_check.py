"""Checking an exported DA3 graph: the contract inputs of the check, the graph's outputs on them in ONNX
Runtime, and their errors against a reference (torch's outputs, or another graph's)."""

from __future__ import annotations

from pathlib import Path

from models.da3.contract import INPUTS, OUTPUTS
from runtime.errors import ModelError

INPUT_NAMES = [name for name, _, _ in INPUTS]
OUTPUT_NAMES = [name for name, _, _ in OUTPUTS]


def check_inputs(n: int, height: int, width: int, seed: int) -> dict:
    """Random contract inputs: images ~ N(0,1), plausible K, normalised poses (view 0 = I)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    images = rng.normal(size=(1, n, 3, height, width)).astype(np.float32)
    K = np.tile(
        np.array([[0.8 * width, 0, width / 2], [0, 0.8 * width, height / 2], [0, 0, 1]]), (1, n, 1, 1)
    )
    E = np.tile(np.eye(4), (1, n, 1, 1))
    for i in range(1, n):
        w = rng.normal(scale=0.1, size=3)
        th = np.linalg.norm(w)
        k = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / th
        E[0, i, :3, :3] = np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * k @ k
        E[0, i, :3, 3] = rng.normal(scale=0.5, size=3)
    return {"images": images, "intrinsics": K.astype(np.float32), "extrinsics": E.astype(np.float32)}


def run_graph(path: Path, inputs: dict, threads: int, providers: list[str] | None = None) -> tuple[dict, str]:
    """The graph's outputs on the check `inputs` (the CPU provider unless `providers` says otherwise), after
    checking that it takes the smallest window (N = 2) too.

    Returns:
        ({"uncond" | "cond": [depth, conf, pred_extrinsics, pred_intrinsics]}, the provider ONNX Runtime
        actually ran: it falls back to the CPU when a requested CUDA provider cannot load).
    """
    import numpy as np

    from models.providers import CPU, create_session

    sess, info = create_session(path, providers=providers or [CPU], threads=threads)
    got = {mode: sess.run(OUTPUT_NAMES, dict(inputs, use_pose=np.array([mode == "cond"])))
           for mode in ("uncond", "cond")}
    n2 = {k: v[:, :2] for k, v in inputs.items()}  # dynamic N: the smallest window runs too
    small = sess.run(OUTPUT_NAMES, dict(n2, use_pose=np.array([True])))
    if small[0].shape[1] != 2:
        raise ModelError(f"{path}: the graph does not accept N=2 views (output {small[0].shape})")
    return got, info["providers"][0]


def output_errors(got: dict, refs: dict, where: Path) -> dict:
    """Per mode and output: max_abs, max_rel (max_abs over the reference's largest magnitude) and the count
    of non-finite values in the output or its reference; any makes max_rel infinite (written as null)."""
    import numpy as np

    errors = {}
    for mode, ref in refs.items():
        for name, g, r in zip(OUTPUT_NAMES, got[mode], ref, strict=True):
            if g.shape != r.shape:
                raise ModelError(f"{where}: output {name} has shape {g.shape}, the reference {r.shape}")
            bad = int(g.size - np.count_nonzero(np.isfinite(g)) + r.size - np.count_nonzero(np.isfinite(r)))
            abs_err = float(np.abs(g - r).max()) if not bad else float("inf")
            errors[f"{mode}.{name}"] = {
                "max_abs": abs_err,
                "max_rel": abs_err / max(float(np.abs(r).max()), 1e-12) if not bad else float("inf"),
                "nonfinite": bad,
            }
    return errors


def worst_error(errors: dict) -> float:
    """The largest max_rel of `errors` (infinite when any output held a non-finite value)."""
    return max((float("inf") if v["nonfinite"] else v["max_rel"]) for v in errors.values())


def compare_with_onnxruntime(
    path: Path, inputs: dict, refs: dict, threads: int, providers: list[str] | None = None
) -> tuple[dict, str]:
    """`output_errors` of ONNX Runtime (the CPU provider unless `providers` says otherwise) against the
    torch references, and the provider that ran (`run_graph`)."""
    got, provider = run_graph(path, inputs, threads, providers)
    return output_errors(got, refs, path), provider
