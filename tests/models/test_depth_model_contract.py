"""checked_prediction: a depth model's output must match the call (N frames of H x W); one that does not
is a ModelError naming the part, which the start-up and the mapper count with its message, never a
half-resolution depth back-projected with the full-size K."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from models.depth_model import DepthPrediction, checked_prediction
from runtime.errors import ModelError
from runtime.events import Frame

N, H, W = 5, 48, 64


def _frames() -> list[Frame]:
    return [Frame(10**9 + k * 200_000_000, np.zeros((H, W), np.uint8)) for k in range(N)]


def _prediction(h: int = H, w: int = W, n: int = N) -> DepthPrediction:
    K = np.tile(np.array([[50.0, 0, w / 2], [0, 50.0, h / 2], [0, 0, 1]]), (n, 1, 1))
    return DepthPrediction(np.ones((n, h, w), np.float32), np.ones((n, h, w), np.float32),
                           np.tile(np.eye(4), (n, 1, 1)), K)


def test_a_prediction_of_the_call_passes_as_it_is() -> None:
    pred = _prediction()
    assert checked_prediction(pred, _frames()) is pred


@pytest.mark.parametrize("change, said", [
    (lambda p: setattr(p, "depth", p.depth[:, ::2, ::2]), "depth of shape (5, 24, 32) for 5 frames of 64x48"),
    (lambda p: setattr(p, "conf", p.conf[:4]), "conf of shape (4, 48, 64)"),
    (lambda p: setattr(p, "T_CW", p.T_CW[:, :3]), "T_CW of shape (5, 3, 4)"),
    (lambda p: setattr(p, "K", None), "K of shape None"),
])
def test_a_prediction_of_other_shapes_is_named(change, said: str) -> None:
    pred = _prediction()
    change(pred)
    with pytest.raises(ModelError, match=said.replace("(", r"\(").replace(")", r"\)")):
        checked_prediction(pred, _frames())


def test_the_mapper_counts_a_model_of_other_shapes_as_a_model_error() -> None:
    """Half-resolution depth and confidence were accepted by the mapping and the start-up."""
    from runtime.mapping.conditioned import depth_call
    from runtime.mapping.config import MappingConfig

    model = SimpleNamespace(K_rect=np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]]),
                            predict=lambda frames, K=None, T_CW=None: _prediction(H // 2, W // 2))
    T_OC = np.tile(np.eye(4), (N, 1, 1))
    T_OC[:, 0, 3] = np.arange(N) * 0.1
    window = SimpleNamespace(frames=_frames(), T_OC=T_OC, window_id=3)
    with pytest.raises(ModelError, match="depth of shape"):
        depth_call(model, window, MappingConfig(), True)
