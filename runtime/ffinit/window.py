"""The data of one start-up window: DA3 points per image plus IMU preintegration to each image.

Frames: C_i = camera at image i, I_i = IMU at image i, i = 0 the reference image.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class ImageObservations:
    """DA3 observations of one image, expressed relative to the reference camera C0.

    Attributes:
        z: (M, 2) normalized image coordinates of the sampled pixels (rectified pinhole).
        depth: (M,) DA3 up-to-scale z-depths of those pixels.
        conf: (M,) DA3 confidences (>= 1).
        R_C0Ci: (3, 3) DA3 relative rotation of camera i in camera 0.
        p_C0Ci: (3,) DA3 up-to-scale position of camera i in camera 0.
    """

    z: np.ndarray
    depth: np.ndarray
    conf: np.ndarray
    R_C0Ci: np.ndarray
    p_C0Ci: np.ndarray

    @property
    def points_C0(self) -> np.ndarray:
        """(M, 3) up-to-scale points in C0: R_C0Ci d z~ + p_C0Ci (paper eq. 1)."""
        zt = np.column_stack([self.z, np.ones(len(self.z))])
        return (self.depth[:, None] * zt) @ self.R_C0Ci.T + self.p_C0Ci


@dataclass
class InitWindow:
    """A start-up window: images, preintegrated IMU from image 0 to each image, extrinsics.

    Attributes:
        t_ns: (N,) image stamps on the IMU clock, int64 ns.
        images: N ImageObservations (image 0 is the reference: R = I, p = 0).
        dt: (N,) seconds from image 0 to image i (dt[0] = 0).
        R_I0Ii: (N, 3, 3) preintegrated rotations at the current bias.
        dp: (N, 3) gravity-free displacement (double integral of rotated specific force) in I0.
        dv: (N, 3) gravity-free velocity change in I0.
        J_R_bg: (N, 3, 3) d(Log R_I0Ii)/d(bg) (right perturbation, Forster).
        J_p_bg, J_p_ba, J_v_bg, J_v_ba: (N, 3, 3) bias Jacobians of dp and dv.
        R_IC: (3, 3) camera-to-IMU rotation; p_IC: (3,) lever arm (camera origin in I).
        bg, ba: (3,) biases the preintegration used.
    """

    t_ns: np.ndarray
    images: list[ImageObservations]
    dt: np.ndarray
    R_I0Ii: np.ndarray
    dp: np.ndarray
    dv: np.ndarray
    J_R_bg: np.ndarray
    J_p_bg: np.ndarray
    J_p_ba: np.ndarray
    J_v_bg: np.ndarray
    J_v_ba: np.ndarray
    R_IC: np.ndarray
    p_IC: np.ndarray
    bg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ba: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def num_images(self) -> int:
        return len(self.images)

    def mean_specific_force_I0(self) -> np.ndarray:
        """Mean specific force over the window in I0 (dv / dt of the last image), m/s^2."""
        return self.dv[-1] / max(self.dt[-1], 1e-9)


@dataclass
class Rejection:
    """Why a window was rejected; `reason` is a short stable key counted in run reports."""

    reason: str
    detail: str = ""
    seed: Any = field(default=None, repr=False, compare=False)
    """An ExtensionSeed when a longer span could cure the rejection (runtime.ffinit.extension)."""
    time_offset_s: float | None = field(default=None, compare=False)
    """A `time_offset` rejection's finding: the camera-IMU offset the window fits (t_imu = t_cam + offset)."""

    def __str__(self) -> str:
        return f"{self.reason}: {self.detail}" if self.detail else self.reason
