"""Unconditioned pose and intrinsics errors of the emulated DA3 (start-up call).

The model predicts camera i relative to camera 0 (world = camera 0). The emulator perturbs the
true relative pose T_C0Ci with sampled errors of the stated distributions; nothing is exact.
"""

from __future__ import annotations

import numpy as np

from models.emulated_da3.params import EmulatorParams
from runtime.geometry import so3_exp


def random_unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) directions uniform on the sphere."""
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def lognormal(rng: np.random.Generator, median: np.ndarray | float, log_sigma: float, n: int) -> np.ndarray:
    """(n,) samples of median * exp(N(0, log_sigma^2))."""
    return np.asarray(median, dtype=np.float64) * np.exp(log_sigma * rng.normal(size=n))


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle(s) in radians of (..., 3, 3) rotation matrices."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def perturb_rotations(
    rng: np.random.Generator, R: np.ndarray, params: EmulatorParams, gain: np.ndarray
) -> np.ndarray:
    """Rotations (n,3,3) times a random error rotation of lognormal angle about a random axis.

    Median angle = gain * (rotation_error_median_deg + rotation_error_frac * true angle).
    """
    n = len(R)
    median = gain * (
        np.deg2rad(params.rotation_error_median_deg) + params.rotation_error_frac * rotation_angle(R)
    )
    ang = lognormal(rng, median, params.rotation_error_log_sigma, n)
    return so3_exp(random_unit_vectors(rng, n) * ang[:, None]) @ R


def perturb_translations(
    rng: np.random.Generator, p: np.ndarray, params: EmulatorParams, gain: np.ndarray, floor_sigma: float
) -> np.ndarray:
    """Camera centres p (n,3) (in camera 0) with direction, length and absolute-floor errors.

    The direction is rotated by a lognormal angle (median gain * translation_direction_median_deg)
    about a random axis perpendicular to p; the length is multiplied by
    exp(N(0, translation_norm_log_sigma)); then N(0, (gain * floor_sigma)^2) is added per axis.
    """
    n = len(p)
    norm = np.linalg.norm(p, axis=1)
    ang = lognormal(
        rng,
        gain * np.deg2rad(params.translation_direction_median_deg),
        params.translation_direction_log_sigma,
        n,
    )
    axis = np.cross(p, random_unit_vectors(rng, n))
    an = np.linalg.norm(axis, axis=1, keepdims=True)
    axis = np.where(an > 1e-12 * np.maximum(norm[:, None], 1e-300), axis / np.maximum(an, 1e-300), 0.0)
    rotated = np.einsum("nij,nj->ni", so3_exp(axis * ang[:, None]), p)
    rotated *= np.exp(params.translation_norm_log_sigma * rng.normal(size=n))[:, None]
    return rotated + rng.normal(size=(n, 3)) * (gain * floor_sigma)[:, None]


def predicted_relative_poses(
    rng: np.random.Generator,
    T_C0Ci: np.ndarray,
    params: EmulatorParams,
    median_depth: float,
    gain: np.ndarray,
) -> np.ndarray:
    """Predicted T_C0Ci (n,4,4), metric units of the truth; entry 0 is exactly the identity.

    Args:
        T_C0Ci: (n,4,4) true poses of camera i in camera 0.
        median_depth: median true depth of the window (m): scales the camera-centre floor.
        gain: (n,) pose-error multipliers (dynamic scenes).
    """
    n = len(T_C0Ci)
    out = np.tile(np.eye(4), (n, 1, 1))
    if n > 1:
        g = gain[1:]
        out[1:, :3, :3] = perturb_rotations(rng, T_C0Ci[1:, :3, :3], params, g)
        out[1:, :3, 3] = perturb_translations(
            rng, T_C0Ci[1:, :3, 3], params, g, params.centre_floor_frac * median_depth
        )
    return out


def predicted_intrinsics(
    rng: np.random.Generator, K_rect: np.ndarray, n: int, params: EmulatorParams
) -> np.ndarray:
    """(n,3,3) predicted intrinsics: fx, fy times one exp(N(0, focal_log_sigma)) per view."""
    K = np.tile(np.asarray(K_rect, np.float64), (n, 1, 1))
    f = np.exp(params.focal_log_sigma * rng.normal(size=n))
    K[:, 0, 0] *= f
    K[:, 1, 1] *= f
    return K
