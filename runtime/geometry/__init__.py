"""Pure math: SO(3)/SE(3), quaternion conventions, interpolation, trajectories (numba kernels)."""
from __future__ import annotations

from runtime.geometry.checks import GeometryError
from runtime.geometry.interpolation import bracket, interpolate_poses
from runtime.geometry.quaternion import (
    jpl_xyzw_to_rot,
    quat_wxyz_to_rot,
    quat_xyzw_to_rot,
    rot_to_jpl_xyzw,
    rot_to_quat_wxyz,
    rot_to_quat_xyzw,
)
from runtime.geometry.se3 import make_pose, se3_exp, se3_inverse, se3_log
from runtime.geometry.so3 import (
    normalize_rotation,
    rot_z,
    skew,
    so3_exp,
    so3_interpolate,
    so3_left_jacobian,
    so3_left_jacobian_inv,
    so3_log,
    so3_right_jacobian,
    so3_right_jacobian_inv,
    vee,
)
from runtime.geometry.trajectory import PoseTrajectory


def kernels_status() -> str:
    """A one-line status of the numba kernels (compiled / cache dir), for `davio info`."""
    import numba

    return f"numba {numba.__version__}, cache dir {numba.config.CACHE_DIR or 'default (__pycache__)'}"


__all__ = [
    "GeometryError", "PoseTrajectory", "bracket", "interpolate_poses", "jpl_xyzw_to_rot", "kernels_status",
    "make_pose", "normalize_rotation", "quat_wxyz_to_rot", "quat_xyzw_to_rot", "rot_to_jpl_xyzw", "rot_z",
    "rot_to_quat_wxyz", "rot_to_quat_xyzw", "se3_exp", "se3_inverse", "se3_log", "skew", "so3_exp",
    "so3_interpolate", "so3_left_jacobian", "so3_left_jacobian_inv", "so3_log", "so3_right_jacobian",
    "so3_right_jacobian_inv", "vee",
]
