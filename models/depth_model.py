"""The depth-model interface shared by the ONNX DA3 backend and the emulated DA3.

Both take a window of camera frames and return, in the *rectified pinhole* view of each frame at
the camera's resolution (see `DepthPrediction.K`):
  * `predict(frames)`: the unconditioned start-up call: up-to-scale depth, confidence,
    predicted relative poses (world = camera 0) and predicted intrinsics;
  * `predict(frames, K, T_CW)`: the pose-conditioned mapping call, with the rectified
    intrinsics and metric world-to-camera poses of every frame; depth is returned metric
    (divided by the similarity scale between input and predicted camera centres).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from runtime.events import Frame


@dataclass
class DepthPrediction:
    """Output of one depth-model call for N frames.

    Attributes:
        depth: (N, H, W) float32 z-depth along the rectified camera's optical axis. Up to one
            unknown global scale for the unconditioned call; metres for the conditioned call.
        conf: (N, H, W) float32 confidence, >= 1, only comparable within a call (use percentiles).
        T_CW: (N, 4, 4) predicted world-to-camera poses. Unconditioned: world = camera 0
            (T_CW[0] = I), translations in the same unknown scale as depth. Conditioned: the
            input poses' world, metric.
        K: (N, 3, 3) intrinsics of the rectified pinhole image the depth lives in, at the camera
            resolution (predicted by the model for the unconditioned call).
        scale: for the conditioned call, the similarity scale s that mapped the input metric
            camera centres onto the predicted ones (depth was divided by it); 1.0 otherwise.
        fit_rmse_m: RMSE (metres) of that similarity fit of camera centres; 0.0 when unconditioned.
        info: backend details (backend name, latency_s, preset, ...).
    """

    depth: np.ndarray
    conf: np.ndarray
    T_CW: np.ndarray
    K: np.ndarray
    scale: float = 1.0
    fit_rmse_m: float = 0.0
    info: dict = field(default_factory=dict)


@runtime_checkable
class DepthModel(Protocol):
    """A multi-view depth model (DA3 through ONNX Runtime, or the emulated DA3)."""

    #: (3, 3) intrinsics of the rectified pinhole view at the camera resolution.
    K_rect: np.ndarray

    def predict(
        self,
        frames: Sequence[Frame],
        K: np.ndarray | None = None,
        T_CW: np.ndarray | None = None,
    ) -> DepthPrediction:
        """Run the model on 2..8 frames; pass both K (N,3,3) and T_CW (N,4,4) to condition."""
        ...


def checked_prediction(pred: object, frames: Sequence[Frame]) -> DepthPrediction:
    """`pred` when it holds what a call on `frames` must return: depth and conf (N, H, W) at the frames'
    size, T_CW (N, 4, 4), K (N, 3, 3). ModelError naming the first part that is not (a model returning
    half-resolution depth was back-projected with the full-size K without a word)."""
    from runtime.errors import ModelError

    n = len(frames)
    h, w = np.asarray(frames[0].image).shape[:2]
    for name, shape in (("depth", (n, h, w)), ("conf", (n, h, w)), ("T_CW", (n, 4, 4)), ("K", (n, 3, 3))):
        value = getattr(pred, name, None)
        got = None if value is None else np.shape(value)
        if got != shape:
            raise ModelError(f"the depth model returned {name} of shape {got} for {n} frames of {w}x{h}: "
                             f"expected {shape} (DepthPrediction, models/depth_model.py)")
    return pred  # type: ignore[return-value]
