"""The pose-conditioned DA3 call of a mapping window and its acceptance gates (paper Sec. V.A).

The worker passes DA3 the window's images, the rectified intrinsics K and the filter's metric poses
T_C_iO. The model wrapper fits a similarity between the input (metric) and the returned camera
centres and divides the depth by its scale s; relative to DA3's own pose normalisation (translations
divided by the median camera distance d to view 0) the depth correction of the window is

    s_hat = 1 / (s d),

which is 1 when the model returns the cameras it was given. The window is accepted only if its
metric baseline exceeds 5 cm, the fit RMSE is at most 15 cm and |log s_hat| <= 0.3.

The unconditioned variant (the reference of the mapping benchmark) calls DA3 without poses and
scales its up-to-scale depth by the similarity between its predicted and the VIO camera centres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.da3.preprocess import camera_centres, normalise_poses
from models.da3.similarity import umeyama_sim3
from models.depth_model import DepthModel, DepthPrediction, checked_prediction
from runtime.mapping.config import MappingConfig
from runtime.mapping.windows import MappingWindow


@dataclass
class WindowFit:
    """Acceptance figures of one window.

    Attributes:
        accepted: the window passed every gate.
        reason: "" when accepted, else "baseline", "fit_rmse", "scale", "model_error" or (set by the mapper
            on the depths) "invalid_depth" or "multiview".
        baseline_m: largest distance between two VIO camera centres of the window (m).
        fit_rmse_m: RMSE of the similarity fit of returned to VIO camera centres (m).
        log_s_hat: log of the depth correction s_hat relative to DA3's pose normalisation.
    """

    accepted: bool
    reason: str
    baseline_m: float
    fit_rmse_m: float = float("nan")
    log_s_hat: float = float("nan")

    def as_dict(self) -> dict:
        return {"baseline_m": self.baseline_m, "fit_rmse_m": self.fit_rmse_m, "log_s_hat": self.log_s_hat}


def window_baseline(T_OC: np.ndarray) -> float:
    """Largest distance (m) between two camera centres of (N,4,4) camera poses."""
    c = np.asarray(T_OC, np.float64)[:, :3, 3]
    return float(np.max(np.linalg.norm(c[:, None] - c[None], axis=2)))


def depth_call(model: DepthModel, window: MappingWindow, cfg: MappingConfig,
               conditioned: bool = True) -> tuple[DepthPrediction | None, WindowFit]:
    """Run the (conditioned) depth call of a window and gate it.

    Returns:
        (prediction with metric depth in the rectified view of `model.K_rect`, or None when the
        window is refused before the call; the gate figures).
    """
    T_OC = np.asarray(window.T_OC, np.float64)
    baseline = window_baseline(T_OC)
    if not baseline > cfg.min_baseline_m:
        return None, WindowFit(False, "baseline", baseline)
    T_CW = np.linalg.inv(T_OC)  # world = O
    n = len(window.frames)
    K = np.tile(np.asarray(model.K_rect, np.float64), (n, 1, 1))
    if conditioned:
        pred = checked_prediction(model.predict(window.frames, K, T_CW), window.frames)
        _, d_norm = normalise_poses(T_CW)
        log_s_hat = -float(np.log(pred.scale * d_norm))
        rmse = float(pred.fit_rmse_m)
    else:
        pred = checked_prediction(model.predict(window.frames), window.frames)
        sim = umeyama_sim3(camera_centres(pred.T_CW), T_OC[:, :3, 3])
        pred.depth = (pred.depth * sim.s).astype(np.float32)
        pred.K = K
        pred.scale = 1.0 / sim.s
        log_s_hat = 0.0  # the unconditioned reference has no normalisation to compare with
        rmse = float(sim.rmse_y)
    fit = WindowFit(True, "", baseline, rmse, log_s_hat)
    if not rmse <= cfg.max_fit_rmse_m:
        fit.accepted, fit.reason = False, "fit_rmse"
    elif not abs(log_s_hat) <= cfg.max_abs_log_scale:
        fit.accepted, fit.reason = False, "scale"
    return pred, fit
