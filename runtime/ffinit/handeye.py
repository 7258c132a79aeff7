"""Calibration-withheld bring-up: camera–IMU rotation and gyro bias by hand–eye alignment of DA3 and
preintegrated relative rotations (paper Sec. IV-D, eq. 9).

For every image i of a window with reference image 0, the residual
    r_i = Log( R_IiI0(bg) R_IC R_C0Ci R_CI ),  R_I0Ii(bg) = R_I0Ii Exp(J_R_bg,i (bg - bg_bar)),
vanishes when R_I0Ii = R_IC R_C0Ci R_CI. R_IC is initialised in closed form from the rotation
axes (alpha_I = R_IC alpha_C, Kabsch), then R_IC and bg are refined jointly (Gauss–Newton), and
the estimate is validated on a later window. The lever arm and time offset start at zero and are
refined online by the filter.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runtime.ffinit.window import Rejection
from runtime.geometry import so3_exp, so3_left_jacobian_inv, so3_log, so3_right_jacobian_inv
from runtime.geometry.so3 import kabsch_rotation


@dataclass
class RotationWindow:
    """Relative rotations of one window, images 1..N-1 against image 0.

    Attributes:
        R_C0Ci: (N-1, 3, 3) relative camera rotations (DA3's, or two-view fits of tracked features).
        R_I0Ii: (N-1, 3, 3) preintegrated IMU rotations at gyro bias `bg_bar`.
        J_R_bg: (N-1, 3, 3) their gyro-bias Jacobians (right perturbation).
        bg_bar: (3,) the gyro bias the preintegration used, rad/s.
        two_view_models: how each camera rotation was found without a model ("essential", "rotation",
            "chained": runtime.bringup); empty for DA3's.
    """

    R_C0Ci: np.ndarray
    R_I0Ii: np.ndarray
    J_R_bg: np.ndarray
    bg_bar: np.ndarray
    two_view_models: tuple[str, ...] = ()


@dataclass
class HandEyeResult:
    """Estimated R_IC and gyro bias with the RMS rotation residual (degrees) over the fit windows."""

    R_IC: np.ndarray
    bg: np.ndarray
    rms_deg: float
    iterations: int
    min_axis_spread: float


def residuals(windows: list[RotationWindow], R_IC: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """(K, 3) residuals of eq. (9) over all windows and images, radians."""
    out = []
    for w in windows:
        dbg = bg - w.bg_bar
        for R_c, R_i, J in zip(w.R_C0Ci, w.R_I0Ii, w.J_R_bg, strict=True):
            R_pre = R_i @ so3_exp(J @ dbg)
            out.append(so3_log(R_pre.T @ R_IC @ R_c @ R_IC.T))
    return np.asarray(out).reshape(-1, 3)


def estimate_handeye(windows: list[RotationWindow], bg0: np.ndarray | None = None,
                     min_axis_spread: float = 0.05, iterations: int = 10,
                     huber_deg: float = 1.0) -> HandEyeResult | Rejection:
    """Closed-form R_IC from rotation axes, then joint Gauss–Newton over (R_IC, bg) with Huber
    weights (threshold huber_deg per residual: DA3's rotation errors are heavy-tailed).

    min_axis_spread: the second singular value of the stacked camera rotation vectors (radians)
    must exceed this, i.e. the motion must rotate about two distinct axes (else R_IC is
    unobservable); the rejection reason says so.
    """
    bg = np.zeros(3) if bg0 is None else np.asarray(bg0, float).copy()
    a_C = np.array([so3_log(R) for w in windows for R in w.R_C0Ci]).reshape(-1, 3)
    a_I = np.array([so3_log(R_i @ so3_exp(J @ (bg - w.bg_bar)))
                    for w in windows for R_i, J in zip(w.R_I0Ii, w.J_R_bg, strict=True)]).reshape(-1, 3)
    if len(a_C) < 2:
        return Rejection("handeye_too_few_rotations", f"{len(a_C)} relative rotations")
    spread = float(np.linalg.svd(a_C, compute_uv=False)[1])
    if spread < min_axis_spread:
        return Rejection("handeye_degenerate_rotation",
                         f"rotation about a single axis (2nd singular value {spread:.3f} rad "
                         f"< {min_axis_spread}); rotate the rig about two axes")
    R_IC = kabsch_rotation(a_C, a_I)
    it = 0
    while it < iterations:
        it += 1
        r = residuals(windows, R_IC, bg)
        rows = []
        k = 0
        for w in windows:
            for R_c, J in zip(w.R_C0Ci, w.J_R_bg, strict=True):
                # perturbations R_IC <- Exp(d_th) R_IC and bg <- bg + d_bg, with X = R_IC R_c R_IC^T:
                # Exp(d) X Exp(-d) = X Exp((X^T - I) d)  =>  dr/d_th = Jr^-1(r) (X^T - I);
                # R_pre(bg + d) = R_pre Exp(J d)          =>  dr/d_bg = -Jl^-1(r) J.
                X = R_IC @ R_c @ R_IC.T
                A_th = so3_right_jacobian_inv(r[k]) @ (X.T - np.eye(3))
                A_bg = -so3_left_jacobian_inv(r[k]) @ J
                rows.append(np.hstack([A_th, A_bg]))
                k += 1
        A = np.vstack(rows)
        norm = np.linalg.norm(r, axis=1)
        thr = np.radians(huber_deg)
        w = np.sqrt(np.where(norm <= thr, 1.0, thr / np.maximum(norm, 1e-12)))
        w3 = np.repeat(w, 3)
        step, *_ = np.linalg.lstsq(A * w3[:, None], -r.ravel() * w3, rcond=None)
        R_IC = so3_exp(step[:3]) @ R_IC
        bg = bg + step[3:]
        if np.linalg.norm(step) < 1e-10:
            break
    rms = float(np.degrees(np.sqrt(np.mean(np.sum(residuals(windows, R_IC, bg) ** 2, axis=1)))))
    return HandEyeResult(R_IC, bg, rms, it, spread)


def validate_handeye(result: HandEyeResult, window: RotationWindow, max_rms_deg: float | None = None,
                     factor: float = 2.5, floor_deg: float = 1.0) -> tuple[bool, float]:
    """RMS residual (degrees) of a later, unused window and whether it passes: at most
    max_rms_deg when given, else at most max(floor_deg, factor x the fit windows' RMS) -- the
    residual level the fit itself showed, so DA3's own rotation noise does not fail it."""
    r = residuals([window], result.R_IC, result.bg)
    rms = float(np.degrees(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))))
    limit = max_rms_deg if max_rms_deg is not None else max(floor_deg, factor * result.rms_deg)
    return rms <= limit, rms
