"""The conditioned call's gates: baseline > 5 cm, fit RMSE <= 15 cm, |log s_hat| <= 0.3."""
from __future__ import annotations

import numpy as np
import pytest
from mapping_synth import H_TEST, K_TEST, W_TEST, window_poses

from models.da3.preprocess import normalise_poses
from models.depth_model import DepthPrediction
from runtime.events import Frame
from runtime.mapping.conditioned import depth_call
from runtime.mapping.config import MappingConfig
from runtime.mapping.windows import MappingWindow


class _FakeModel:
    """Returns the input poses with a chosen similarity scale and fit RMSE (as the wrapper does)."""

    K_rect = K_TEST

    def __init__(self, log_s_hat: float = 0.0, rmse: float = 0.01) -> None:
        self.log_s_hat, self.rmse, self.calls = log_s_hat, rmse, 0

    def predict(self, frames, K=None, T_CW=None):
        self.calls += 1
        _, d = normalise_poses(T_CW)
        s = np.exp(-self.log_s_hat) / d
        n = len(frames)
        ones = np.ones((n, H_TEST, W_TEST), np.float32)
        return DepthPrediction(ones, ones.copy(), T_CW, K, s, self.rmse)


def _window(step: float) -> MappingWindow:
    frames = [Frame(k, np.zeros((H_TEST, W_TEST), np.uint8)) for k in range(5)]
    return MappingWindow(0, frames, window_poses(5, step), 0)


@pytest.mark.parametrize("step, log_s, rmse, reason", [
    (0.15, 0.0, 0.01, ""),
    (0.15, 0.29, 0.149, ""),
    (0.15, 0.31, 0.01, "scale"),
    (0.15, -0.31, 0.01, "scale"),
    (0.15, 0.0, 0.151, "fit_rmse"),
    (0.0124, 0.0, 0.01, "baseline"),     # 4 x 1.24 cm = 4.96 cm
    (0.0126, 0.0, 0.01, ""),             # 5.04 cm
])
def test_gates(step, log_s, rmse, reason):
    model = _FakeModel(log_s, rmse)
    pred, fit = depth_call(model, _window(step), MappingConfig())
    assert fit.reason == reason and fit.accepted == (reason == "")
    if reason == "baseline":
        assert pred is None and model.calls == 0       # refused before the model runs
    else:
        assert np.isclose(fit.log_s_hat, log_s)
