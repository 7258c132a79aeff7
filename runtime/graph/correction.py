"""The odometry-to-map correction T_MO over sensor time (paper Sec. V.D, eq. correction).

Frames: O = the odometry (filter world) frame, M = the map frame, I = the IMU/body, S_j = the centre
camera of submap j. Each map commit defines a target correction from its newest node j,
T_MO = T_MS_j T_S_jO, and live poses are published as T_MI(t) = T_MO(t) T_OI(t).

Causal trajectory (`CorrectionTimeline`): every pose uses the correction in effect at its own sensor
time, i.e. the newest commit at or before it. A change larger than `trans_threshold_m` or
`rot_threshold_deg` is blended in over `interpolation_s` of sensor time, starting at the commit's time,
from the correction in effect at that instant (itself possibly mid-blend) to the target: linear in
translation, along the SO(3) geodesic in rotation. Smaller changes apply at once. Each published pose
records the version of that commit and its blend fraction (1 when complete or immediate).

Final trajectory (`final_corrections`): "the final export applies the completed corrections to all past
poses" is read as follows. After the last graph update every node j has a final correction
T_MO_j = T_MS_j T_S_jO, anchored at its centre keyframe time; a pose at time t receives the correction
interpolated between the two nodes bracketing t (linear translation, geodesic rotation), held constant
before the first and after the last node, and the identity when there are no nodes. No temporal blending
is involved: the blend only exists to keep the live stream continuous.

Translation differences are measured between the translation columns of the two corrections (the same
quantity the blend interpolates linearly); rotation differences are the geodesic angle |Log(R0^T R1)|.
Time is int64 ns of the sensor clock; seconds appear only inside the math.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from runtime.geometry import bracket, make_pose, so3_interpolate, so3_log
from runtime.graph.factors import GraphError, check_pose


@dataclass
class CorrectionConfig:
    """When and how a new odometry-to-map correction is blended into the live stream."""

    trans_threshold_m: float = 0.05
    """A change of the correction's translation above this (m) is interpolated instead of applied at once."""
    rot_threshold_deg: float = 2.0
    """A change of the correction's rotation above this geodesic angle (deg) is interpolated."""
    interpolation_s: float = 1.0
    """Duration of the blend, in seconds of sensor time, starting at the commit's sensor time."""

    def __post_init__(self) -> None:
        for name in ("trans_threshold_m", "rot_threshold_deg", "interpolation_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise GraphError(f"CorrectionConfig.{name} must be finite and >= 0, got {value!r}")

    @property
    def interpolation_ns(self) -> int:
        return int(round(self.interpolation_s * 1e9))


@dataclass(frozen=True)
class PublishedCorrection:
    """A live pose in the map frame: T_MI (4,4), the correction version and its blend fraction in [0, 1]."""

    T_MI: np.ndarray
    version: int
    fraction: float


@dataclass(frozen=True)
class _Commit:
    t_ns: int
    version: int
    T_from: np.ndarray
    """(4,4) the correction in effect at t_ns just before this commit."""
    T_to: np.ndarray
    """(4,4) the target correction of this commit."""
    duration_ns: int
    """0 for an immediate change, else the blend duration."""


def interpolate_correction(T0: np.ndarray, T1: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Corrections between T0 and T1 (each (..., 4, 4)) at fractions alpha (...): linear translation,
    geodesic rotation R0 Exp(alpha Log(R0^T R1)); alpha = 0 gives T0, 1 gives T1 exactly."""
    alpha = np.asarray(alpha, dtype=np.float64)
    R = so3_interpolate(T0[..., :3, :3], T1[..., :3, :3], alpha)
    p = T0[..., :3, 3] + alpha[..., None] * (T1[..., :3, 3] - T0[..., :3, 3])
    out = make_pose(R, p)
    # make the end points exact (no round trip through Log/Exp)
    out = np.where((alpha == 0.0)[..., None, None], np.broadcast_to(T0, out.shape), out)
    return np.where((alpha == 1.0)[..., None, None], np.broadcast_to(T1, out.shape), out)


def correction_change(T0: np.ndarray, T1: np.ndarray) -> tuple[float, float]:
    """(translation change in m, rotation change in deg) between two (4,4) corrections."""
    dp = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
    dr = float(np.degrees(np.linalg.norm(so3_log(T0[:3, :3].T @ T1[:3, :3]))))
    return dp, dr


class CorrectionTimeline:
    """The correction T_MO in effect at each sensor time, built from the map commits in time order.

    Versions start above 0 (version 0 means "no commit yet": identity correction) and must increase;
    commit times must not decrease (two commits at one time: the later one starts from the earlier one's
    state at that time). Queries (`at`, `apply`) may come in any order.
    """

    def __init__(self, config: CorrectionConfig | None = None) -> None:
        self.config = config or CorrectionConfig()
        self._t: list[int] = []
        self._commits: list[_Commit] = []

    def __len__(self) -> int:
        return len(self._commits)

    @property
    def version(self) -> int:
        """The newest committed version (0 before any commit)."""
        return self._commits[-1].version if self._commits else 0

    @property
    def last_commit_ns(self) -> int | None:
        """Sensor time of the newest commit (None before any)."""
        return self._t[-1] if self._t else None

    def commit(self, t_ns: int, T_MO: np.ndarray, version: int, immediate: bool = False) -> bool:
        """Add a map commit at sensor time t_ns with target correction T_MO (4,4) and a new version;
        `immediate` applies it at once whatever its size (a first transform, with nothing to blend from).

        Returns True when the change is blended over the interpolation time, False when it applies at once.
        Raises GraphError (a ValueError) for a malformed pose, a non-increasing version or a commit older
        than the previous one.
        """
        t_ns = int(t_ns)
        version = int(version)
        T_MO = check_pose(T_MO, "T_MO")
        if version <= self.version:
            raise GraphError(f"correction version {version} must be greater than the previous {self.version}")
        if self._t and t_ns < self._t[-1]:
            raise GraphError(f"correction commit at {t_ns} ns is older than the previous one "
                             f"at {self._t[-1]} ns")
        T_from, _, _ = self.at(t_ns)
        dp, dr = correction_change(T_from, T_MO)
        blend = not immediate and (dp > self.config.trans_threshold_m or dr > self.config.rot_threshold_deg)
        duration = self.config.interpolation_ns if blend else 0
        self._t.append(t_ns)
        self._commits.append(_Commit(t_ns, version, T_from, T_MO, duration))
        return blend and duration > 0

    def at(self, t_ns: int) -> tuple[np.ndarray, int, float]:
        """(T_MO (4,4), version, fraction) in effect for a pose published at sensor time t_ns."""
        k = bisect.bisect_right(self._t, int(t_ns)) - 1
        if k < 0:
            return np.eye(4), 0, 1.0
        c = self._commits[k]
        elapsed = int(t_ns) - c.t_ns
        if elapsed >= c.duration_ns:
            return c.T_to.copy(), c.version, 1.0
        fraction = elapsed / c.duration_ns
        return interpolate_correction(c.T_from, c.T_to, fraction), c.version, fraction

    def apply(self, t_ns: int, T_OI: np.ndarray) -> PublishedCorrection:
        """The live map-frame pose T_MI = T_MO(t) T_OI of an odometry pose T_OI (4,4) at t_ns."""
        T_OI = np.asarray(T_OI, dtype=np.float64)
        if T_OI.shape != (4, 4) or not np.all(np.isfinite(T_OI)):
            raise GraphError(f"T_OI must be a finite (4,4) pose, got shape {T_OI.shape}")
        T_MO, version, fraction = self.at(t_ns)
        return PublishedCorrection(T_MO @ T_OI, version, fraction)


def final_corrections(t_ns: np.ndarray, node_t_ns: np.ndarray, node_T_MO: np.ndarray) -> np.ndarray:
    """Final corrections (N,4,4) at pose times t_ns (N,) from the per-node corrections after the last update.

    node_t_ns (J,) are the nodes' centre keyframe times (distinct; any order) and node_T_MO (J,4,4) their
    corrections T_MS_j T_S_jO. Between two nodes the correction is interpolated (linear translation,
    geodesic rotation); before the first and after the last node it is held constant; with no nodes it is
    the identity. The final trajectory is T_MI(t) = final_corrections(t) @ T_OI(t).
    """
    t_ns = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    node_t_ns = np.asarray(node_t_ns, dtype=np.int64).reshape(-1)
    node_T_MO = np.asarray(node_T_MO, dtype=np.float64)
    if node_T_MO.shape != (node_t_ns.size, 4, 4):
        raise GraphError(f"node_T_MO must have shape ({node_t_ns.size}, 4, 4), got {node_T_MO.shape}")
    if node_t_ns.size == 0:
        return np.broadcast_to(np.eye(4), (t_ns.size, 4, 4)).copy()
    if not np.all(np.isfinite(node_T_MO)):
        raise GraphError("node_T_MO holds non-finite values")
    order = np.argsort(node_t_ns, kind="stable")
    node_t_ns, node_T_MO = node_t_ns[order], node_T_MO[order]
    if np.any(np.diff(node_t_ns) == 0):
        dup = int(node_t_ns[1:][np.diff(node_t_ns) == 0][0])
        raise GraphError(f"two nodes share the time {dup} ns")
    i, alpha = bracket(node_t_ns, np.clip(t_ns, node_t_ns[0], node_t_ns[-1]))
    j = np.minimum(i + 1, node_t_ns.size - 1)
    return interpolate_correction(node_T_MO[i], node_T_MO[j], alpha)
