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


@pytest.mark.parametrize("t_gain, reason", [(1.0, ""), (2.0, "scale")])
def test_onnx_graph_path_through_the_gates(tmp_path, monkeypatch, t_gain, reason):
    """The same call through a real ONNX graph (the DA3 contract graph: it returns the input poses with
    translations times t_gain, i.e. s_hat = 1 / t_gain) and the OnnxDA3 wrapper."""
    from pathlib import Path

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "models"))
    from da3_contract_graph import build_da3_contract_graph

    from calib.camera import Pinhole
    from models.da3 import OnnxDA3

    graph = build_da3_contract_graph(tmp_path / "g.onnx", 28, 42, t_gain=t_gain)
    cam = Pinhole(W_TEST, H_TEST, K_TEST[0, 0], K_TEST[1, 1], K_TEST[0, 2], K_TEST[1, 2])
    model = OnnxDA3(graph, cam)
    pred, fit = depth_call(model, _window(0.15), MappingConfig())
    assert fit.reason == reason
    assert np.isclose(fit.log_s_hat, -np.log(t_gain), atol=1e-5) and fit.fit_rmse_m < 1e-5
    assert pred.depth.shape == (5, H_TEST, W_TEST) and np.isfinite(pred.depth).all()
