"""Absolute and relative trajectory errors (ATE, RPE), with evo-compatible definitions.

ATE: after association and alignment, e_i = || p_ref_i - p_est_i || (metres) and the rotation
error angle |Log(R_ref_i^T R_est_i)| (degrees), as evo_ape's translation_part / angle_deg.
RPE: for index pairs (i, j) chosen on the estimate (every `delta` frames, or every `delta` metres
of travelled path), E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) with Q reference and P estimate poses;
the translation error is |t(E)| and the rotation error |Log(R(E))|, as evo_rpe.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from runtime.errors import TrajectoryError
from runtime.geometry import so3_log
from runtime.geometry.trajectory import PoseTrajectory
from tools.evaluation.align import Alignment, align
from tools.evaluation.associate import associate


def error_stats(err: np.ndarray) -> dict[str, float]:
    """rmse, mean, median, std (population), min, max, sse of an error vector (evo's statistics)."""
    e = np.asarray(err, dtype=np.float64)
    if e.size == 0:
        raise TrajectoryError("no errors to summarise (empty pose set)")
    return {"rmse": float(np.sqrt(np.mean(e * e))), "mean": float(np.mean(e)),
            "median": float(np.median(e)), "std": float(np.std(e)), "min": float(np.min(e)),
            "max": float(np.max(e)), "sse": float(np.sum(e * e))}


def rotation_angles_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angles |Log(R_a^T R_b)| in degrees of (N, 3, 3) rotation pairs."""
    rel = np.einsum("nji,njk->nik", R_a, R_b)
    return np.degrees(np.linalg.norm(so3_log(rel), axis=-1))


@dataclass
class AteResult:
    """Absolute trajectory error of an associated, aligned estimate.

    Attributes:
        t_ns: (N,) stamps of the associated estimate poses.
        trans_err_m: (N,) position errors, metres.
        rot_err_deg: (N,) orientation errors, degrees.
        alignment: the alignment applied to the estimate.
        est_aligned, ref: the associated trajectories (estimate after alignment).
        n_est, n_ref: pose counts of the input files.
    """

    t_ns: np.ndarray
    trans_err_m: np.ndarray
    rot_err_deg: np.ndarray
    alignment: Alignment
    est_aligned: PoseTrajectory
    ref: PoseTrajectory
    n_est: int
    n_ref: int
    max_diff_s: float = 0.01
    trans: dict[str, float] = field(init=False)
    rot: dict[str, float] = field(init=False)

    def __post_init__(self) -> None:
        self.trans = error_stats(self.trans_err_m)
        self.rot = error_stats(self.rot_err_deg)

    @property
    def rmse(self) -> float:
        """Translation ATE RMSE, metres."""
        return self.trans["rmse"]

    def as_dict(self) -> dict:
        """JSON-ready summary: `rmse` is the translation RMSE in metres."""
        return {"metric": "ate", "rmse": self.rmse, "unit": "m", "translation_m": self.trans,
                "rotation_deg": self.rot, "pairs": int(self.t_ns.size), "n_est": self.n_est,
                "n_ref": self.n_ref, "max_diff_s": self.max_diff_s, "alignment": self.alignment.as_dict(),
                "path_length_ref_m": self.ref.path_length()}


def ate(est: PoseTrajectory, ref: PoseTrajectory, align_method: str = "se3", max_diff_s: float = 0.01,
        offset_s: float = 0.0, n_align: int | None = None, one_to_one: bool = False) -> AteResult:
    """ATE of `est` against `ref`: associate (nearest stamps within max_diff_s), align, compare.

    Args:
        est, ref: trajectories T_WB with int64 ns stamps.
        align_method: "se3", "sim3", "posyaw" or "none".
        max_diff_s: association tolerance, seconds.
        offset_s: added to the estimate's stamps for association.
        n_align: fit the alignment on the first n associated poses only.
        one_to_one: pair each pose at most once (see `associate`).
    """
    est_m, ref_m = associate(est, ref, max_diff_s, offset_s, one_to_one)
    est_a, alignment = align(est_m, ref_m, align_method, n_align)
    trans = np.linalg.norm(ref_m.p - est_a.p, axis=1)
    rot = rotation_angles_deg(ref_m.R, est_a.R)
    return AteResult(est_m.t_ns.copy(), trans, rot, alignment, est_a, ref_m, len(est), len(ref), max_diff_s)


def pairs_by_frames(n: int, delta: int, all_pairs: bool = False) -> np.ndarray:
    """(K, 2) index pairs `delta` poses apart: consecutive (0,d),(d,2d).. or all (i, i+d)."""
    if delta < 1:
        raise TrajectoryError(f"RPE delta must be at least 1 frame, got {delta}")
    if all_pairs:
        i = np.arange(max(n - delta, 0))
        return np.stack([i, i + delta], axis=1)
    ids = np.arange(0, n, delta)
    return np.stack([ids[:-1], ids[1:]], axis=1)


def pairs_by_path(p: np.ndarray, delta_m: float, rel_tol: float = 0.1, all_pairs: bool = False) -> np.ndarray:
    """(K, 2) index pairs about `delta_m` metres of travelled path apart (evo's definition).

    Consecutive mode starts at pose 0 and closes a pair as soon as the path since the pair's first
    pose reaches delta_m; all-pairs mode takes, for every i, the j whose path distance is closest to
    delta_m if within rel_tol * delta_m.
    """
    if delta_m <= 0:
        raise TrajectoryError(f"RPE delta must be positive, got {delta_m} m")
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if all_pairs:
        dist = np.concatenate([[0.0], np.cumsum(step)])
        out = []
        for i in range(dist.size - 1):
            ahead = dist[i + 1:] - dist[i]
            j = int(np.argmin(np.abs(ahead - delta_m)))
            if abs(ahead[j] - delta_m) <= delta_m * rel_tol:
                out.append((i, i + 1 + j))
        return np.array(out, dtype=np.int64).reshape(-1, 2)
    ids = [0]
    acc = 0.0
    for k, d in enumerate(step, start=1):
        acc += float(d)
        if acc >= delta_m:
            ids.append(k)
            acc = 0.0
    ids_a = np.array(ids, dtype=np.int64)
    return np.stack([ids_a[:-1], ids_a[1:]], axis=1)


@dataclass
class RpeResult:
    """Relative pose error over index pairs of an associated pair of trajectories.

    Attributes:
        pairs: (K, 2) index pairs into the associated trajectories.
        trans_err_m: (K,) |t(E)|, metres. rot_err_deg: (K,) |Log(R(E))|, degrees.
    """

    pairs: np.ndarray
    t_ns: np.ndarray
    trans_err_m: np.ndarray
    rot_err_deg: np.ndarray
    delta: float
    delta_unit: str
    alignment: Alignment
    trans: dict[str, float] = field(init=False)
    rot: dict[str, float] = field(init=False)

    def __post_init__(self) -> None:
        self.trans = error_stats(self.trans_err_m)
        self.rot = error_stats(self.rot_err_deg)

    @property
    def rmse(self) -> float:
        """Translation RPE RMSE, metres."""
        return self.trans["rmse"]

    def as_dict(self) -> dict:
        """JSON-ready summary: `rmse` is the translation RPE RMSE in metres."""
        return {"metric": "rpe", "rmse": self.rmse, "unit": "m", "translation_m": self.trans,
                "rotation_deg": self.rot, "pairs": int(self.pairs.shape[0]), "delta": self.delta,
                "delta_unit": self.delta_unit, "alignment": self.alignment.as_dict()}


def rpe(est: PoseTrajectory, ref: PoseTrajectory, delta: float = 1, delta_unit: str = "f",
        all_pairs: bool = False, rel_tol: float = 0.1, align_method: str = "none",
        max_diff_s: float = 0.01, offset_s: float = 0.0, one_to_one: bool = False) -> RpeResult:
    """RPE of `est` against `ref` (evo_rpe semantics; pairs are chosen on the estimate).

    Args:
        delta: pair spacing, in frames ("f") or metres of the estimate's path ("m").
        delta_unit: "f" or "m".
        all_pairs: every pose starts a pair (else consecutive, non-overlapping pairs).
        rel_tol: accepted relative path mismatch in all-pairs metre mode.
        align_method: alignment applied before (only "sim3"'s scale changes the result).
        max_diff_s, offset_s, one_to_one: association settings (see `associate`).
    """
    est_m, ref_m = associate(est, ref, max_diff_s, offset_s, one_to_one)
    est_a, alignment = align(est_m, ref_m, align_method)
    if delta_unit == "f":
        if float(delta) != int(delta):
            raise TrajectoryError(f"RPE delta in frames must be an integer, got {delta}")
        pairs = pairs_by_frames(len(est_a), int(delta), all_pairs)
    elif delta_unit == "m":
        pairs = pairs_by_path(est_a.p, float(delta), rel_tol, all_pairs)
    else:
        raise TrajectoryError(f"unknown RPE delta unit {delta_unit!r}; expected 'f' (frames) or 'm' (metres)")
    if pairs.shape[0] == 0:
        raise TrajectoryError(f"delta {delta} {delta_unit} leaves no pose pair among {len(est_a)} poses")
    i, j = pairs[:, 0], pairs[:, 1]
    # relative motions Q_i^-1 Q_j and P_i^-1 P_j
    Rq = np.einsum("nji,njk->nik", ref_m.R[i], ref_m.R[j])
    tq = np.einsum("nji,nj->ni", ref_m.R[i], ref_m.p[j] - ref_m.p[i])
    Rp = np.einsum("nji,njk->nik", est_a.R[i], est_a.R[j])
    tp = np.einsum("nji,nj->ni", est_a.R[i], est_a.p[j] - est_a.p[i])
    # E = Q_rel^-1 P_rel: t(E) = Rq^T (tp - tq), R(E) = Rq^T Rp
    trans = np.linalg.norm(np.einsum("nji,nj->ni", Rq, tp - tq), axis=1)
    rot = rotation_angles_deg(Rq, Rp)
    return RpeResult(pairs, est_m.t_ns[j], trans, rot, float(delta), delta_unit, alignment)
