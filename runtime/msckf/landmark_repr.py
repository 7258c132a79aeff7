"""Anchored inverse-depth landmarks (OpenVINS ANCHORED_MSCKF_INVERSE_DEPTH), as numba kernels.

A landmark is lam = [alpha, beta, rho] = [x/z, y/z, 1/z] of its position p_A = (x, y, z) in the anchor
camera, the camera of one clone (R_OI, p_OI) with extrinsics (R_IC, p_IC):
    p_O = R_OI (R_IC p_A + p_IC) + p_OI.
Error states: lam additive, clone [dtheta (right), dp], extrinsics [dphi (right on R_IC), dp_IC].
"""

from __future__ import annotations

import numpy as np
from numba import njit

from runtime.msckf.so3_kernels import skew3


@njit(cache=True, nogil=True)
def lam_to_anchor_point(lam: np.ndarray) -> np.ndarray:
    """[alpha, beta, rho] -> p_A."""
    return np.array([lam[0] / lam[2], lam[1] / lam[2], 1.0 / lam[2]])


@njit(cache=True, nogil=True)
def anchor_point_to_lam(p: np.ndarray) -> np.ndarray:
    """p_A -> [x/z, y/z, 1/z]."""
    return np.array([p[0] / p[2], p[1] / p[2], 1.0 / p[2]])


@njit(cache=True, nogil=True)
def d_lam_d_point(p: np.ndarray) -> np.ndarray:
    """d lam / d p_A at p_A."""
    z = p[2]
    z2 = z * z
    return np.array([[1.0 / z, 0.0, -p[0] / z2], [0.0, 1.0 / z, -p[1] / z2], [0.0, 0.0, -1.0 / z2]])


@njit(cache=True, nogil=True)
def anchored_to_global(lam: np.ndarray, R_A: np.ndarray, p_A: np.ndarray, R_IC: np.ndarray,
                       p_IC: np.ndarray) -> tuple:
    """p_O and its Jacobians: d p_O / d lam (3,3), d / d anchor clone (3,6), d / d extrinsics (3,6)."""
    pa = lam_to_anchor_point(lam)
    q = R_IC @ pa + p_IC                      # point in the anchor IMU frame
    p_O = R_A @ q + p_A
    rho = lam[2]
    dpa = np.array([[1.0 / rho, 0.0, -lam[0] / (rho * rho)], [0.0, 1.0 / rho, -lam[1] / (rho * rho)],
                    [0.0, 0.0, -1.0 / (rho * rho)]])
    J_lam = R_A @ R_IC @ dpa
    J_anchor = np.zeros((3, 6))
    J_anchor[:, 0:3] = -R_A @ skew3(q)
    J_anchor[:, 3:6] = np.eye(3)
    J_ext = np.zeros((3, 6))
    J_ext[:, 0:3] = -R_A @ R_IC @ skew3(pa)
    J_ext[:, 3:6] = R_A
    return p_O, J_lam, J_anchor, J_ext


@njit(cache=True, nogil=True)
def global_to_anchored(p_O: np.ndarray, R_A: np.ndarray, p_A: np.ndarray, R_IC: np.ndarray,
                       p_IC: np.ndarray) -> tuple:
    """lam of p_O in the anchor camera, and its Jacobians: d lam / d p_O (3,3), d / d anchor clone (3,6),
    d / d extrinsics (3,6)."""
    q = R_A.T @ (p_O - p_A)
    pa = R_IC.T @ (q - p_IC)
    D = d_lam_d_point(pa)
    A = R_IC.T @ R_A.T
    J_p = D @ A
    J_anchor = np.zeros((3, 6))
    J_anchor[:, 0:3] = D @ (R_IC.T @ skew3(q))
    J_anchor[:, 3:6] = -D @ A
    J_ext = np.zeros((3, 6))
    J_ext[:, 0:3] = D @ skew3(pa)
    J_ext[:, 3:6] = -D @ R_IC.T
    return anchor_point_to_lam(pa), J_p, J_anchor, J_ext
