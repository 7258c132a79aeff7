"""Offline replay of a mapper on a recorded tracking run: its causal and final map-frame trajectories.

Given a `TrackingRun` (trajectory_inputs.py), a mapper processes the recorded windows in the live
processing order, and its commits are applied as `VioPipeline` applies them:
  * causal: each commit applied during tracking goes into its segment's `CorrectionTimeline` at
    max(the pipeline's last IMU time when the result arrived, that timeline's previous commit time); a
    published pose gets T_MO(t) T_OI(t) from the timelines as they stood when it was published (the
    commits applied before it), exactly `VioPipeline.causal`;
  * final: every committed submap's final graph state gives its node correction
    T_MO_j = T_MS_j T_OS_j^-1 at its centre keyframe time (IMU clock); every published pose gets the
    correction interpolated between its segment's nodes (`final_corrections`). Commits the live stream
    never applied (windows mapped after the recording ended, and the job in flight at its end) count
    here: the final trajectory is re-exported "with all corrections after the last graph update".
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from runtime.geometry.trajectory import PoseTrajectory
from runtime.graph.correction import CorrectionTimeline, final_corrections
from tools.benchmarks.mapping_variants import keep_submaps
from tools.benchmarks.trajectory_inputs import TrackingRun


@dataclass
class Replay:
    """A mapper's result on a tracking run.

    Attributes:
        causal: (N,4,4) T_MI of every published state as the live stream would publish it.
        versions, fractions: (N,) the correction version and blend fraction of each causal pose.
        final: (N,4,4) T_MI re-exported with the final per-node corrections.
        submaps: the committed submaps (final states, including changes reported for submaps that had
            left the mapper's memory), in commit order.
        commits: commits made; applied: commits applied to the live stream during tracking.
        seconds: wall time of the mapping.
    """

    causal: np.ndarray
    versions: np.ndarray
    fractions: np.ndarray
    final: np.ndarray
    submaps: list = field(default_factory=list)
    commits: int = 0
    applied: int = 0
    seconds: float = 0.0


def odometry_poses(published: list) -> np.ndarray:
    """(N,4,4) T_OI of the published states."""
    T = np.tile(np.eye(4), (len(published), 1, 1))
    for k, p in enumerate(published):
        T[k, :3, :3], T[k, :3, 3] = p.R_OI, p.p_OI
    return T


def node_corrections(submaps: list, time_offset_ns: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per segment: (centre times on the IMU clock (J,), final corrections T_MS T_OS^-1 (J,4,4))."""
    by_seg: dict[int, list] = {}
    for sm in submaps:
        t = int(sm.frame_t_ns[sm.centre]) + int(time_offset_ns)
        by_seg.setdefault(int(sm.segment), []).append((t, sm.T_MS @ np.linalg.inv(sm.T_OS)))
    return {s: (np.array([t for t, _ in v], np.int64), np.array([T for _, T in v]).reshape(-1, 4, 4))
            for s, v in by_seg.items()}


def final_poses(published: list, submaps: list, time_offset_ns: int) -> np.ndarray:
    """(N,4,4) every published pose with the completed corrections of its segment's nodes (identity for a
    segment without nodes), as `VioPipeline.final_poses`."""
    T_OI = odometry_poses(published)
    out = T_OI.copy()
    nodes = node_corrections(submaps, time_offset_ns)
    seg = np.array([p.segment for p in published], np.int64)
    t = np.array([p.t_ns for p in published], np.int64)
    for s in np.unique(seg):
        idx = np.nonzero(seg == s)[0]
        t_n, T_n = nodes.get(int(s), (np.zeros(0, np.int64), np.zeros((0, 4, 4))))
        corr = final_corrections(t[idx], t_n, T_n)
        out[idx] = corr @ T_OI[idx]
    return out


def replay(run: TrackingRun, mapper: Any) -> Replay:
    """Map the run's windows with `mapper` (a fresh runtime.mapping.Mapper) and build the causal and final
    trajectories (module docstring)."""
    from runtime.mapping.mapper import MapCommit

    T_OI = odometry_poses(run.published)
    n = len(run.published)
    causal = T_OI.copy()
    versions = np.zeros(n, np.int64)
    fractions = np.ones(n)
    timelines: dict[int, CorrectionTimeline] = {}
    done = 0

    def publish_until(k_end: int) -> None:
        nonlocal done
        for k in range(done, k_end):
            p = run.published[k]
            tl = timelines.get(p.segment)
            if tl is not None:
                c = tl.apply(int(p.t_ns), T_OI[k])
                causal[k], versions[k], fractions[k] = c.T_MI, c.version, c.fraction
        done = max(done, k_end)

    submaps = []
    by_index: dict[int, Any] = {}
    applied = 0
    t0 = time.perf_counter()
    for slot in run.slots:
        mapper.stats.windows_offered += 1
        result = mapper.process(slot.window)
        commit = result if isinstance(result, MapCommit) else None
        if commit is not None:
            submaps.append(commit.submap)
            keep_submaps(commit, by_index)
        if slot.applied is None:
            continue
        n_before, t_last = slot.applied
        publish_until(n_before)
        if commit is not None:
            tl = timelines.setdefault(commit.submap.segment, CorrectionTimeline())
            tl.commit(max(t_last, tl.last_commit_ns or 0), commit.T_MO, commit.version)
            applied += 1
    publish_until(n)
    seconds = time.perf_counter() - t0
    return Replay(causal, versions, fractions, final_poses(run.published, submaps, run.time_offset_ns),
                  submaps, len(submaps), applied, seconds)


def trajectory(published: list, T_MI: np.ndarray, idx: np.ndarray | None = None) -> PoseTrajectory:
    """The poses T_MI (N,4,4) of the published states (rows `idx`, default all) as a trajectory."""
    idx = np.arange(len(published)) if idx is None else np.asarray(idx, np.int64)
    if idx.size == 0:
        return PoseTrajectory(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)))
    return PoseTrajectory([published[k].t_ns for k in idx], T_MI[idx, :3, 3], T_MI[idx, :3, :3])
