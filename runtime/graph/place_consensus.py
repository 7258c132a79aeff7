"""Verified place pairs between two map sessions, and what they agree on: the hypotheses' consensus and
the yaw-and-translation transform fitted to it (steps 3 and 4 of `runtime.graph.relocalize`)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from runtime.geometry.se3 import make_pose
from runtime.geometry.se3 import yaw_translation_fit as fit_yaw
from runtime.geometry.so3 import rot_z
from runtime.graph.factors import GraphError

if TYPE_CHECKING:
    from runtime.graph.relocalize import AlignConfig


@dataclass
class Hypothesis:
    """One verified pair (prior view a, new view b) and the transform it implies.

    Attributes:
        prior, new: submap indices of a and b.
        T_PN: (4,4) the pair's transform from the new map frame to the prior one.
        yaw_deg: its yaw; tilt_deg: how far it tilts the vertical.
        n_inliers: PnP inliers; depth_rel_error: the pair's median relative depth error.
        x_P, x_N: (K,3) the pair's correspondences placed in the prior and the new map frame.
        c_N: (3,) the new view's camera centre in the new map frame (its centre in the prior frame by
            this pair is T_PN c_N).
    """

    prior: int
    new: int
    T_PN: np.ndarray
    yaw_deg: float
    tilt_deg: float
    n_inliers: int
    depth_rel_error: float
    x_P: np.ndarray
    x_N: np.ndarray
    c_N: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def as_dict(self) -> dict:
        return {"prior": self.prior, "new": self.new, "yaw_deg": self.yaw_deg, "tilt_deg": self.tilt_deg,
                "t": [float(v) for v in self.T_PN[:3, 3]], "n_inliers": self.n_inliers,
                "depth_rel_error": self.depth_rel_error, "n_points": int(len(self.x_P))}


def yaw_deg(R: np.ndarray) -> float:
    """Yaw (degrees) of the rotation about z nearest to R (Frobenius)."""
    return float(np.degrees(np.arctan2(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1])))


def tilt_deg(R: np.ndarray) -> float:
    """Angle (degrees) by which R tilts the vertical (z) axis."""
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


def yaw_translation_fit(x_P: np.ndarray, x_N: np.ndarray) -> np.ndarray:
    """(4,4) T = [Rz(yaw), t] minimising sum |x_P - T x_N|^2 over (K,3) point pairs (closed form,
    `runtime.geometry.se3.yaw_translation_fit`)."""
    x_P = np.asarray(x_P, np.float64)
    x_N = np.asarray(x_N, np.float64)
    if x_P.shape != x_N.shape or x_P.ndim != 2 or x_P.shape[1] != 3 or len(x_P) < 2:
        raise GraphError(f"need two or more (K,3) point pairs, got {x_P.shape} and {x_N.shape}")
    R, t, _ = fit_yaw(x_N, x_P)
    return make_pose(R, t)


def agreement(hyps: list[Hypothesis], cfg: AlignConfig, block: int = 256) -> np.ndarray:
    """(n,n) bool: hypotheses i and j agree: yaws within agree_deg, and the two transforms put the
    midpoint of their new camera centres within agree_m of each other. (Compared where the views are:
    at the new map's origin, which may lie tens of metres away, a yaw difference of a degree would
    already move the translations apart.) Computed `block` rows at a time."""
    n = len(hyps)
    yaw = np.array([h.yaw_deg for h in hyps])
    R = np.array([h.T_PN[:3, :3] for h in hyps]).reshape(n, 3, 3)
    t = np.array([h.T_PN[:3, 3] for h in hyps]).reshape(n, 3)
    c = np.array([h.c_N for h in hyps]).reshape(n, 3)
    dyaw = (yaw[:, None] - yaw[None, :] + 180.0) % 360.0 - 180.0
    out = np.abs(dyaw) <= cfg.agree_deg
    for a in range(0, n, block):
        b = min(n, a + block)
        m = 0.5 * (c[a:b, None, :] + c[None, :, :])                       # (rows, n, 3)
        p_i = np.einsum("iab,ijb->ija", R[a:b], m) + t[a:b, None, :]
        p_j = np.einsum("jab,ijb->ija", R, m) + t[None, :, :]
        out[a:b] &= np.linalg.norm(p_i - p_j, axis=2) <= cfg.agree_m
    return out


def _gap_m(T_a: np.ndarray, T_b: np.ndarray, c_N: np.ndarray) -> float:
    """Distance (m) between where two transforms T_PN put new-frame point c_N (3,)."""
    c = np.asarray(c_N, np.float64)
    return float(np.linalg.norm(T_a[:3, :3] @ c + T_a[:3, 3] - T_b[:3, :3] @ c - T_b[:3, 3]))


def transforms_agree(T_a: np.ndarray, T_b: np.ndarray, c_N: np.ndarray, cfg: AlignConfig) -> bool:
    """Whether two transforms T_PN agree as two hypotheses do (`agreement`): yaws within agree_deg and
    new-frame point c_N (3,) placed within agree_m by both."""
    dyaw = (yaw_deg(T_a[:3, :3]) - yaw_deg(T_b[:3, :3]) + 180.0) % 360.0 - 180.0
    return bool(abs(dyaw) <= cfg.agree_deg and _gap_m(T_a, T_b, c_N) <= cfg.agree_m)


def replaces(old_group: list[Hypothesis], old_T: np.ndarray, group: list[Hypothesis], T: np.ndarray,
             held: set[int], cfg: AlignConfig) -> bool:
    """Whether consensus `group` (transform T) replaces the last one (`old_group`, `old_T`) rather than
    refining it: the two transforms disagree at the new group's cameras (`transforms_agree`), the groups
    share no hypothesis, and either some of the old group are still held (`held`: ids of the hypotheses
    kept) and so outvoted, or, when all were dropped, the transforms lie more than half the revisit search
    radius apart (a drifting refinement whose old pairs aged out is not a replacement)."""
    c = np.mean([h.c_N for h in group], axis=0)
    if transforms_agree(old_T, T, c, cfg):
        return False
    old_ids = {id(h) for h in old_group}
    if old_ids & {id(h) for h in group}:
        return False
    if old_ids & held:
        return True
    return _gap_m(old_T, T, c) > 0.5 * cfg.gates.candidate_radius_m


def _largest_group(A: np.ndarray, new: np.ndarray, idx: np.ndarray) -> tuple[int, np.ndarray]:
    """(centre, members): among hypotheses `idx`, the one whose agreeing members (within `idx`) come
    from the most distinct new views (then the most members), and those members."""
    best, best_key = -1, (-1, -1)
    members = np.zeros(0, np.int64)
    for i in idx:
        m = idx[A[i, idx]]
        key = (len(np.unique(new[m])), len(m))
        if key > best_key:
            best, best_key, members = int(i), key, m
    return best, members


def consensus(hyps: list[Hypothesis], cfg: AlignConfig) -> tuple[list[int], str]:
    """(agreeing indices, reason): the largest group of mutually consistent hypotheses (those agreeing
    with one centre hypothesis), refused when it spans fewer than `min_views` new views or when a group
    elsewhere (hypotheses agreeing with neither the centre nor its group) also spans `min_views` and
    more than half as many."""
    if not hyps:
        return [], "no candidate pair passed verification"
    A = agreement(hyps, cfg)
    new = np.array([h.new for h in hyps])
    centre, group = _largest_group(A, new, np.arange(len(hyps)))
    views = len(np.unique(new[group]))
    if views < cfg.min_views:
        return [], (f"the largest consistent group comes from {views} new view(s), fewer than "
                    f"{cfg.min_views}")
    rest = np.flatnonzero(~A[centre] & ~A[group].any(axis=0))
    other_views = len(np.unique(new[_largest_group(A, new, rest)[1]])) if len(rest) else 0
    if other_views >= cfg.min_views and other_views * 2 > views:
        return [], (f"ambiguous: two inconsistent groups of {views} and {other_views} new views (a "
                    "repetitive place, or a different one)")
    return [int(k) for k in group], "localized"


def rms(x_P: np.ndarray, x_N: np.ndarray, T_PN: np.ndarray) -> float:
    """RMS distance (m) between (K,3) points x_P and T_PN x_N."""
    return float(np.sqrt(np.mean(np.sum((x_P - (x_N @ T_PN[:3, :3].T + T_PN[:3, 3])) ** 2, axis=1))))


def centres(group: list[Hypothesis]) -> tuple[np.ndarray, np.ndarray]:
    """(c_P, c_N): each hypothesis's new camera centre in the prior frame by its own T_PN, and in N."""
    c_N = np.array([h.c_N for h in group])
    return np.array([h.T_PN[:3, :3] @ h.c_N + h.T_PN[:3, 3] for h in group]), c_N


def fit_transform(group: list[Hypothesis], cfg: AlignConfig) -> tuple[np.ndarray, str]:
    """T_PN from the agreeing hypotheses and which fit gave it ("centres" or "mean yaw";
    `runtime.graph.relocalize`, step 4)."""
    c_P, c_N = centres(group)
    spread = float(np.sqrt(np.mean(np.sum((c_N[:, :2] - c_N[:, :2].mean(axis=0)) ** 2, axis=1))))
    if spread >= cfg.min_centre_spread_m:
        T = yaw_translation_fit(c_P, c_N)
        new = np.array([h.new for h in group])
        for _ in range(2):      # trim pairs whose centre lies beyond 3x the median residual, refit
            r = np.linalg.norm(c_P - (c_N @ T[:3, :3].T + T[:3, 3]), axis=1)
            keep = r <= 3.0 * np.median(r)
            if len(np.unique(new[keep])) < cfg.min_views or keep.all():
                break
            T = yaw_translation_fit(c_P[keep], c_N[keep])
        return T, "centres"
    yaws = np.radians([h.yaw_deg for h in group])
    yaw = float(np.arctan2(np.mean(np.sin(yaws)), np.mean(np.cos(yaws))))
    R = rot_z(yaw)
    return make_pose(R, np.mean(c_P - c_N @ R.T, axis=0)), "mean yaw"
