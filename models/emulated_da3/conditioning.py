"""Geometry of the emulated pose-conditioned call.

The images show the true scene from the true cameras; the model is told the input poses. The
emulated model places the scene in the input world with the similarity S that best maps the
true cameras onto the input ones (what the images can tell up to scale), puts its own cameras at
the input poses pulled by `cond_image_weight` towards S(true camera), and returns each pixel's
depth as seen from its own camera. So a wrong input pose passes into the depth; a window whose
input poses are a similarity of the truth (e.g. a VIO scale error) gives depth in that similarity's
scale. The DA3 wrapper's pose normalisation and Umeyama fit are reproduced for the reported scale.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Below this spread (m) of camera centres a similarity scale is not observable (as in the ONNX wrapper).
MIN_CENTRE_SPREAD_M = 1e-3
#: DA3's clamp of the pose-normalisation distance (m).
MIN_POSE_SCALE_M = 0.1


def camera_centres(T_CW: np.ndarray) -> np.ndarray:
    """(N,3) camera centres in the world of (N,4,4) world-to-camera poses."""
    return -np.einsum("nji,nj->ni", T_CW[:, :3, :3], T_CW[:, :3, 3])


def pose_normalisation_distance(T_CW: np.ndarray) -> float:
    """DA3's translation normaliser (m): lower median over all N views of the distance to view 0, >= 0.1."""
    c = camera_centres(T_CW)
    dist = np.sort(np.linalg.norm(c - c[0], axis=1))
    return max(float(dist[(len(dist) - 1) // 2]), MIN_POSE_SCALE_M)


def median_consecutive_baseline(centres: np.ndarray) -> float:
    """Median distance (m) between consecutive camera centres (N,3) of a window."""
    return float(np.median(np.linalg.norm(np.diff(centres, axis=0), axis=1)))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) to a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


@dataclass(frozen=True)
class Sim3:
    """x' = s R x + t (s > 0)."""

    s: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Map points (...,3)."""
        return self.s * x @ self.R.T + self.t


def umeyama(x: np.ndarray, y: np.ndarray) -> tuple[Sim3, float, float]:
    """Least-squares similarity mapping x (N,3) onto y (N,3) (Umeyama 1991).

    Returns (sim, rmse of the residuals in y's units, RMS spread of x about its centroid).
    The caller checks the spread before trusting the scale.
    """
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    var_x = float((xc**2).sum(1).mean())
    spread = float(np.sqrt(var_x))
    U, d, Vt = np.linalg.svd(yc.T @ xc / len(x))
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0])
    R = U @ S @ Vt
    s = float(np.trace(np.diag(d) @ S) / var_x) if var_x > 0 else 1.0
    t = my - s * R @ mx
    res = y - (s * x @ R.T + t)
    return Sim3(s, R, t), float(np.sqrt((res**2).sum(1).mean())), spread


def true_to_input_similarity(
    T_WC_true: np.ndarray, T_CW_in: np.ndarray, mono_scale: float
) -> tuple[Sim3, bool]:
    """The similarity S mapping the true world onto the input world, and whether its scale was observable.

    Rotation: the chordal mean of R_WC_in_i R_WC_true_i^T. Scale: least squares of the centred
    input centres on the rotated centred true ones (an input error across the motion leaves it
    unchanged); when the true centres do not move (spread < MIN_CENTRE_SPREAD_M) or the fitted
    input spread is that small or negative, the images give no metric cue and `mono_scale` (a
    sampled monocular guess) is used. Translation: centroids agree (camera 0 in that case).
    """
    R_WC_in = np.transpose(T_CW_in[:, :3, :3], (0, 2, 1))
    R = project_to_so3(np.einsum("nij,nkj->ik", R_WC_in, T_WC_true[:, :3, :3]))
    c_true = T_WC_true[:, :3, 3]
    c_in = camera_centres(T_CW_in)
    x = (c_true - c_true.mean(0)) @ R.T
    y = c_in - c_in.mean(0)
    var_true = float((x**2).sum(1).mean())
    s = float((x * y).sum(1).mean() / var_true) if var_true > 0 else 0.0
    if np.sqrt(var_true) < MIN_CENTRE_SPREAD_M or not s * np.sqrt(var_true) >= MIN_CENTRE_SPREAD_M:
        return Sim3(mono_scale, R, c_in[0] - mono_scale * R @ c_true[0]), False
    return Sim3(s, R, c_in.mean(0) - s * R @ c_true.mean(0)), True


def model_camera_centres(
    T_WC_true: np.ndarray, T_CW_in: np.ndarray, S: Sim3, image_weight: float
) -> np.ndarray:
    """(N,3) the model's camera centres (input world): input centres pulled towards S(true centres)."""
    c_in = camera_centres(T_CW_in)
    return c_in + image_weight * (S.apply(T_WC_true[:, :3, 3]) - c_in)


def conditioned_depth(
    depth_true: np.ndarray,
    K: np.ndarray,
    T_WC_true: np.ndarray,
    S: Sim3,
    R_CW_model: np.ndarray,
    c_model: np.ndarray,
) -> np.ndarray:
    """Depth (H,W) of each pixel's scene point S(X_true) seen from the model's camera (input world units).

    X_true(u) = T_WC_true (d(u) K^-1 u); depth = e3 . R_CW_model (S(X_true) - c_model). inf stays inf
    (no surface). Values can be <= 0 when the input pose puts the point behind the camera; the
    caller clamps them.
    """
    H, W = depth_true.shape
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    Kinv = np.linalg.inv(K)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ Kinv.T  # z = 1
    a = S.s * (R_CW_model[2] @ S.R @ T_WC_true[:3, :3])  # (3,)
    b = float(R_CW_model[2] @ (S.apply(T_WC_true[:3, 3]) - c_model))
    finite = np.isfinite(depth_true)
    d = np.where(finite, depth_true, 0.0)
    out = d * (rays @ a) + b
    return np.where(finite, out, np.inf)
