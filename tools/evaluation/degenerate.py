"""ATE where the truth's positions cannot fix an alignment rotation (a static or straight-line truth:
pure rotation in place, hover, constant velocity)."""
from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np


def ate_degenerate_truth(est: Any, gt: Any) -> Any:
    """The SE(3) ATE where the truth's positions cannot fix a rotation (static or collinear): the
    gravity-aligned frames differ by yaw and translation, so position + yaw alignment; where the truth does
    not move horizontally (standing, turning in place, or moving only vertically), yaw is not fixed by the
    positions and the score is the translation-aligned error: the RMS of (estimate - truth) at the
    estimate's stamps about its mean, which for a static truth is the estimate's spread (the yaw is then
    taken from the first orientations, for the velocity error). None when the estimate does not overlap
    the truth.

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
    t_in = est.t_ns[inside]
    d = est.p[inside] - interpolate_poses(gt, t_in).p
    rmse = float(np.sqrt(np.mean(np.sum((d - d.mean(axis=0)) ** 2, axis=1))))
    R_off = interpolate_poses(gt, t_in[:1]).R[0] @ est.R[inside][0].T
    R_yaw = rot_z(np.arctan2(R_off[1, 0], R_off[0, 0]))
    return SimpleNamespace(trans={"rmse": rmse}, alignment=SimpleNamespace(R=R_yaw, s=1.0))


def truth_is_degenerate(est: Any, gt: Any) -> bool:
    """True when the truth's positions over the estimate's stamps are static or collinear, so that no
    SE(3) rotation can be fitted to them (the case `ate_degenerate_truth` scores); False when fewer than
    3 estimate stamps fall inside the truth (let the ordinary ATE report that)."""
    from runtime.geometry import interpolate_poses

    inside = (est.t_ns >= gt.t_ns[0]) & (est.t_ns <= gt.t_ns[-1])
    if np.count_nonzero(inside) < 3:
        return False
    p = interpolate_poses(gt, est.t_ns[inside]).p
    sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return bool(sv[1] <= 1e-9 * max(1.0, float(sv[0])))
