"""ATE where the truth's positions cannot fix an alignment rotation (a static or straight-line truth:
pure rotation in place, hover, constant velocity)."""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np


def ate_degenerate_truth(est: Any, gt: Any) -> Any:
    """The SE(3) ATE where the truth's positions cannot fix a rotation (static or collinear): the
    gravity-aligned frames differ by yaw and translation, so position + yaw alignment; where the truth does
    not move horizontally either, any rotation maps the estimate onto it equally well and the best fit
    leaves the estimate's spread about its mean (the yaw is then taken from the first orientations, for
    the velocity error). None when the estimate does not overlap the truth.

    Args:
        est, gt: PoseTrajectory (gravity-aligned frames, positions in metres).

    Returns an AteResult (posyaw), or a namespace with trans["rmse"] and alignment.R / .s.
    """
    from runtime.errors import DataError
    from runtime.geometry import interpolate_poses, rot_z
    from tools.evaluation.metrics import ate

    try:
        return ate(est, gt, align_method="posyaw")
    except DataError:
        pass
    inside = (est.t_ns >= gt.t_ns[0]) & (est.t_ns <= gt.t_ns[-1])
    if np.count_nonzero(inside) < 3:
        return None
    p = est.p[inside]
    rmse = float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))
    R_off = interpolate_poses(gt, est.t_ns[inside][:1]).R[0] @ est.R[inside][0].T
    R_yaw = rot_z(np.arctan2(R_off[1, 0], R_off[0, 0]))
    return SimpleNamespace(trans={"rmse": rmse}, alignment=SimpleNamespace(R=R_yaw, s=1.0))
