"""Figures of `davio bench trajectory` beyond ATE: coverage, first-state time, the odometry's drift per
distance travelled, and reference figures for that drift from the shared data.

Coverage (paper Sec. VI): the fraction of the sequence [start, end] covered by published poses, each
pose crediting at most `credit_s` (0.1 s): the measure of the union of [t_k, t_k + credit_s] clipped to
the sequence, so repeated or closely spaced poses are not counted twice.

Drift per distance: the estimate is anchored at its first pose (position and heading about gravity: roll
and pitch are observable, the VIO's yaw and origin are not) and the position error at the last pose is
divided by the true path length between them (x 100: per cent of distance, i.e. m per 100 m). RPE over
10 m of travelled path (`tools.evaluation.rpe`, all pairs) gives the translation error per 10 m segment.
"""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

from runtime.geometry.trajectory import PoseTrajectory

COVERAGE_CREDIT_S = 0.1
RPE_SEGMENT_M = 10.0

PAPER_OPENVINS_MH03_ATE_M = 0.158
"""OpenVINS alone on EuRoC MH_03_medium (median of three mapping-disabled runs), ATE in m, SE(3)
alignment: the paper's Table "EuRoC ATE" (spec/davio_paper.tex, Sec. VII, Q2), row MH_03, column Native."""


def coverage(t_ns: np.ndarray, start_ns: int, end_ns: int, credit_s: float = COVERAGE_CREDIT_S) -> float:
    """Fraction of [start_ns, end_ns] covered by the poses at t_ns, each crediting at most credit_s."""
    span = int(end_ns) - int(start_ns)
    if span <= 0:
        return 0.0
    t = np.unique(np.clip(np.asarray(t_ns, np.int64), start_ns, end_ns))
    if t.size == 0:
        return 0.0
    credit = int(round(credit_s * 1e9))
    nxt = np.append(t[1:], np.int64(end_ns))
    covered = np.minimum(nxt - t, credit)
    return float(covered.sum()) / span


def first_state_s(first_publish_t_ns: int | None, start_ns: int) -> float | None:
    """T_f: sensor seconds from the sequence start to the first published state (None if none)."""
    return None if first_publish_t_ns is None else (int(first_publish_t_ns) - int(start_ns)) * 1e-9


def path_length(p: np.ndarray) -> float:
    """Length of the polyline through the positions p (N,3), metres."""
    p = np.asarray(p, np.float64).reshape(-1, 3)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def _yaw_of(R: np.ndarray) -> float:
    """The rotation about z closest to R (3,3) on its xy block (least squares)."""
    return float(np.arctan2(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1]))


def start_anchored_drift(est: PoseTrajectory, ref: PoseTrajectory) -> dict:
    """Drift of `est` against `ref` (both T_WI, gravity-aligned) anchored at the first associated pose.

    Returns: path_m (true path length over the associated span), end_error_m (position error at the last
    pose), percent (end_error_m / path_m x 100), seconds (span).
    """
    from tools.evaluation import associate

    e, r = associate(est, ref)
    yaw = _yaw_of(r.R[0] @ e.R[0].T)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t = r.p[0] - R @ e.p[0]
    end_err = float(np.linalg.norm(R @ e.p[-1] + t - r.p[-1]))
    path = path_length(r.p)
    return {"path_m": path, "end_error_m": end_err, "percent": 100.0 * end_err / path if path > 0 else None,
            "seconds": float((e.t_ns[-1] - e.t_ns[0]) * 1e-9)}


def rpe_per_distance(est: PoseTrajectory, ref: PoseTrajectory,
                     segment_m: float = RPE_SEGMENT_M) -> dict | None:
    """Translation RPE over `segment_m` of travelled path (all pairs): mean and RMSE in m and per cent of
    the segment; None when the path is shorter than one segment."""
    from runtime.errors import TrajectoryError
    from tools.evaluation import rpe

    try:
        r = rpe(est, ref, delta=segment_m, delta_unit="m", all_pairs=True)
    except TrajectoryError:
        return None
    return {"segment_m": segment_m, "pairs": int(len(r.pairs)), "mean_m": r.trans["mean"],
            "rmse_m": r.trans["rmse"], "mean_percent": 100.0 * r.trans["mean"] / segment_m}


def odometry_drift(est: PoseTrajectory, ref: PoseTrajectory, ate_m: float) -> dict:
    """The odometry's drift figures: start-anchored end error per distance, RPE per 10 m, ATE per path."""
    d = start_anchored_drift(est, ref)
    d["rpe"] = rpe_per_distance(est, ref)
    d["ate_percent_of_path"] = 100.0 * ate_m / d["path_m"] if d["path_m"] > 0 else None
    return d


def _jpl_to_R_WI(q_xyzw: np.ndarray) -> np.ndarray:
    """R_WI (N,3,3) from JPL quaternions q_GtoI (N,4) stored x, y, z, w:
    R_GtoI = (2w^2-1) I - 2w [v]x + 2 v v^T (shared/data/README.md), R_WI = R_GtoI^T."""
    q = np.asarray(q_xyzw, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    v, w = q[:, :3], q[:, 3]
    vx = np.zeros((len(q), 3, 3))
    vx[:, 0, 1], vx[:, 0, 2], vx[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    vx = vx - np.transpose(vx, (0, 2, 1))
    R_GtoI = ((2 * w * w - 1)[:, None, None] * np.eye(3) - 2 * w[:, None, None] * vx
              + 2 * np.einsum("ni,nj->nij", v, v))
    return np.transpose(R_GtoI, (0, 2, 1))


def openvins_sim_anchor(folder: Path) -> dict | None:
    """OpenVINS's own estimate on the OpenVINS simulator (shared/data/openvins_sim/<run>/est_vs_gt.csv.gz:
    one row per frame, estimate and truth side by side) through the same drift figures; None if absent.

    The file's time column is printed with too few digits to associate by time; rows are frames of a fixed
    camera rate, so the poses are stamped by row index (the rate only scales time, not the figures)."""
    path = Path(folder) / "est_vs_gt.csv.gz"
    if not path.is_file():
        return None
    with gzip.open(path, "rt") as fh:
        data = np.loadtxt(fh, comments="#")
    t = np.arange(len(data), dtype=np.int64) * 50_000_000
    est = PoseTrajectory(t, data[:, 5:8], _jpl_to_R_WI(data[:, 1:5]))
    ref = PoseTrajectory(t, data[:, 21:24], _jpl_to_R_WI(data[:, 17:21]))
    ate_m = float(np.sqrt(np.mean(np.sum((est.p - ref.p) ** 2, axis=1))))
    out = odometry_drift(est, ref, ate_m)
    out.update({"source": str(path), "what": f"OpenVINS 2.7 on the OpenVINS simulator ({Path(folder).name}), "
                "its own estimate, initialised from the true state; position RMSE without alignment",
                "ate_m": ate_m})
    return out


def paper_mh03_anchor(groundtruth: PoseTrajectory | None) -> dict | None:
    """OpenVINS on real EuRoC MH_03 (the paper's native ATE) per metre of the true MH_03 path; None
    without the ground truth."""
    if groundtruth is None or len(groundtruth) < 2:
        return None
    # the ground truth at 200 Hz: its path at 0.1 s steps (jitter of the 5 ms steps would add length)
    step = max(1, int(round(0.1e9 / max(np.median(np.diff(groundtruth.t_ns)), 1))))
    path = path_length(groundtruth.p[::step])
    return {"ate_m": PAPER_OPENVINS_MH03_ATE_M, "path_m": path,
            "ate_percent_of_path": 100.0 * PAPER_OPENVINS_MH03_ATE_M / path,
            "source": "paper Table 'EuRoC ATE' (MH_03 Native) over the MH_03_medium ground-truth path"}
