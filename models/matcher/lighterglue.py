"""LighterGlue (XFeat's LightGlue) through ONNX Runtime: keypoints + descriptors of two images -> matches.

The graph (`davio export-xfeat --lighterglue PATH`) returns the log assignment matrix; matches are
its mutual row/column maxima whose probability exceeds `min_conf` (LightGlue's own rule).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from models.matcher.contract import check_lighterglue_signature
from models.matcher.features import Features
from models.onnx_file import require_file
from models.providers import create_session, quiet_run_options
from runtime.errors import ModelError


def normalise_keypoints(kpts: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixels -> LightGlue's frame: (k - size / 2) / (max(size) / 2), float32 (N, 2)."""
    return ((np.asarray(kpts, np.float32) - [width / 2, height / 2]) / (max(width, height) / 2)).astype(
        np.float32
    )


def assignment_matches(
    log_assignment: np.ndarray, min_conf: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mutual maxima of a (M+1, N+1) log assignment (dustbins last) with probability > min_conf."""
    S = log_assignment[:-1, :-1]
    if S.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    best_ab, best_ba = S.argmax(axis=1), S.argmax(axis=0)
    idx_a = np.flatnonzero(best_ba[best_ab] == np.arange(S.shape[0]))
    idx_b = best_ab[idx_a]
    p = np.exp(S[idx_a, idx_b])
    keep = p > min_conf
    return idx_a[keep].astype(np.int64), idx_b[keep].astype(np.int64), p[keep].astype(np.float32)


class LighterGlue:
    """LighterGlue ONNX matcher for XFeat features.

    Args:
        model_path: the exported graph; min_conf: match probability threshold (upstream 0.1).
        providers, threads: ONNX Runtime session settings.
    """

    def __init__(
        self,
        model_path: str | Path,
        min_conf: float = 0.1,
        providers: Sequence[str] | None = None,
        threads: int | None = None,
    ) -> None:
        path = Path(model_path)
        require_file(path, missing=f"LighterGlue model not found: {path}. Export it with: "
                                   f"davio export-xfeat --lighterglue {path}")
        self.path, self.min_conf = path, min_conf
        self.session, self.session_info = create_session(
            path, providers, threads, contract=check_lighterglue_signature
        )

        def sig(args):
            return [(a.name, a.type, [d if isinstance(d, int) else None for d in a.shape]) for a in args]

        check_lighterglue_signature(
            sig(self.session.get_inputs()), sig(self.session.get_outputs()), str(path)
        )

    def match(
        self, fa: Features, fb: Features, size_a: tuple[int, int], size_b: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(idx_a, idx_b, probability) for two XFeat feature sets; sizes are (width, height) pixels."""
        if len(fa) < 2 or len(fb) < 2:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
        feeds = {
            "kpts0": normalise_keypoints(fa.kpts, *size_a)[None],
            "kpts1": normalise_keypoints(fb.kpts, *size_b)[None],
            "desc0": fa.desc.astype(np.float32)[None],
            "desc1": fb.desc.astype(np.float32)[None],
        }
        try:
            (scores,) = self.session.run(["log_assignment"], feeds, quiet_run_options())
        except Exception as exc:
            raise ModelError(f"{self.path}: inference failed ({type(exc).__name__}: {exc})") from exc
        return assignment_matches(scores[0], self.min_conf)
