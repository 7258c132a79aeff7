"""What the emulated DA3 needs from a simulator: rendered ground-truth views (typing only).

`models/` must not import the simulator (`drivers/sim`); any object with this shape works, e.g.
the simulator's ground truth or `models.emulated_da3.analytic.BoxRoom`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from runtime.errors import DataError


@runtime_checkable
class GroundTruthView(Protocol):
    """Ground truth of one camera view.

    Attributes:
        depth: (H, W) float32 z-depth (m) of an undistorted pinhole camera with the requested K at
            the true pose; np.inf where the ray hits nothing.
        T_WC: (4, 4) true camera-to-world pose.
        texture: (H, W) float32 texture strength in [0, 1] (0 = featureless).
        reflective: (H, W) bool, pixel on a reflective / transparent surface.
        dynamic: (H, W) bool, pixel on a moving object.
        surface_id: (H, W) int32 id of the surface hit (-1 = none).
    """

    depth: np.ndarray
    T_WC: np.ndarray
    texture: np.ndarray
    reflective: np.ndarray
    dynamic: np.ndarray
    surface_id: np.ndarray


@runtime_checkable
class GroundTruthSource(Protocol):
    """Renders ground-truth views: depth and surface attributes at the true pose of time t_ns."""

    def render_view(self, t_ns: int, K: np.ndarray, width: int, height: int) -> GroundTruthView:
        """The ground truth seen at camera time t_ns (int64 ns) through pinhole K (3,3), W x H pixels."""
        ...


def check_view(view: GroundTruthView, t_ns: int, width: int, height: int) -> None:
    """Raise DataError when a rendered view does not have the promised shapes and values."""
    hw = (height, width)
    for name in ("depth", "texture", "reflective", "dynamic", "surface_id"):
        arr = np.asarray(getattr(view, name))
        if arr.shape != hw:
            raise DataError(f"ground-truth view at t_ns={t_ns}: {name} has shape {arr.shape}, expected {hw}")
    T = np.asarray(view.T_WC, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise DataError(f"ground-truth view at t_ns={t_ns}: T_WC must be a finite (4,4) pose, got {T.shape}")
    d = np.asarray(view.depth)
    if np.isnan(d).any() or (d <= 0).any():
        raise DataError(f"ground-truth view at t_ns={t_ns}: depth must be > 0 or inf (no NaN)")
