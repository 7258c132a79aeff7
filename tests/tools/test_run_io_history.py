"""write_run builds its trajectories and pose table from the history's columns: the files must be what the
per-state objects give (published_segments / published_trajectory, the causal tuples), restarts included."""
from __future__ import annotations

import json

import numpy as np
from scipy.spatial.transform import Rotation

from runtime.config import DavioConfig
from runtime.geometry.trajectory import PoseTrajectory
from runtime.pose_history import PoseHistory
from runtime.scheduler import SchedulerReport
from runtime.startup import Published
from tools.evaluation import read_tum
from tools.run_io import published_segments, published_trajectory, write_run


class _Pipeline:
    """What write_run reads of a VioPipeline: the history, its views, final poses, start-up and report."""

    def __init__(self, history: PoseHistory, final: list[np.ndarray]) -> None:
        self.history, self.published, self.causal = history, history.published, history.causal
        self._final = final
        self.startup = None

    def final_poses(self) -> list[np.ndarray]:
        return self._final

    def report(self) -> dict:
        return {}


def _history(rng: np.random.Generator, n: int = 30, restart: int | None = 12) -> tuple[PoseHistory, list]:
    h = PoseHistory()
    given = []
    for k in range(n):
        seg = 0 if restart is None or k < restart else 1     # a restart after pose `restart`
        p = Published(10**18 + 50_000_000 * k, 10**18 + 50_000_000 * k - 3,
                      Rotation.random(random_state=k).as_matrix(), rng.normal(size=3), rng.normal(size=3),
                      "native:dynamic" if seg == 0 else "feedforward", seg, seg)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rotation.random(random_state=100 + k).as_matrix(), rng.normal(size=3)
        h.append(p, T, k // 5, 0.25 * (k % 4))
        given.append((p, T, k // 5, 0.25 * (k % 4)))
    return h, given


def _same(a, b) -> None:
    """The same poses: stamps and positions exactly (TUM round-trips floats), rotations to rounding (the
    file stores a quaternion)."""
    assert np.array_equal(a.t_ns, b.t_ns) and np.array_equal(a.p, b.p)
    np.testing.assert_allclose(a.R, b.R, atol=1e-14, rtol=0)


def _poses(t_ns, T) -> PoseTrajectory:
    T = np.asarray(T)
    return PoseTrajectory(t_ns, T[:, :3, 3], T[:, :3, :3])


def test_run_files_from_columns_equal_the_per_state_objects(tmp_path) -> None:
    rng = np.random.default_rng(1)
    h, given = _history(rng)
    final = [T @ _offset(k) for k, (_, T, _, _) in enumerate(given)]       # not the causal poses
    report = write_run(tmp_path, _Pipeline(h, final), SchedulerReport(), None, {}, DavioConfig())
    objects = [p for p, _, _, _ in given]
    segs = published_segments(objects)
    assert [len(s) for s in segs] == [12, 18]
    for k, seg in enumerate(segs):
        _same(read_tum(tmp_path / f"odometry_segment{k}.tum"), published_trajectory(seg))
    for k, (a, b) in enumerate([(0, 12), (12, 30)]):     # each segment's map frame, as published and final
        t_seg = [p.t_ns for p, _, _, _ in given[a:b]]
        _same(read_tum(tmp_path / f"causal_segment{k}.tum"), _poses(t_seg, [T for _, T, _, _ in given[a:b]]))
        _same(read_tum(tmp_path / f"final_segment{k}.tum"), _poses(t_seg, final[a:b]))
    _same(read_tum(tmp_path / "odometry.tum"), published_trajectory(segs[-1]))
    t_last = [p.t_ns for p in segs[-1]]
    _same(read_tum(tmp_path / "causal.tum"), _poses(t_last, [T for _, T, _, _ in given[12:]]))
    _same(read_tum(tmp_path / "final.tum"), _poses(t_last, final[12:]))
    lines = (tmp_path / "poses.csv").read_text().splitlines()
    assert lines[1:] == [f"{p.t_ns},{p.t_cam_ns},{p.segment},{p.source},{v},{f:.6f}" for p, _, v, f in given]
    assert report["published_poses"] == 30 and report["metrics_segment"] == 1
    assert report["segments"] == [
        {"poses": 12, "start_t_ns": objects[0].t_ns, "source": "native:dynamic", "metrics": {}},
        {"poses": 18, "start_t_ns": objects[12].t_ns, "source": "feedforward", "metrics": {}}]   # no gt
    assert json.loads((tmp_path / "report.json").read_text())["segments"] == report["segments"]


def test_after_a_reset_each_segment_is_scored_in_its_own_frame_and_the_console_says_so(tmp_path, capsys
                                                                                        ) -> None:
    """The ATE and causal.tum / final.tum cover the last segment only: a 5-pose tail after three resets
    was printed as the run's ATE. Ground truth here is each segment's odometry poses moved by its own
    rigid transform (the frames of a reset filter): every segment scores 0 alone, not all together."""
    from tools.run_summary import _last_segment_scope, segments_line

    rng = np.random.default_rng(3)
    h, given = _history(rng)
    final = [T for _, T, _, _ in given]
    gt_p = []
    for k, (p, _, _, _) in enumerate(given):
        R = Rotation.from_rotvec([0.0, 0.0, 0.0 if k < 12 else 1.0]).as_matrix()
        gt_p.append(R @ p.p_OI + (0.0 if k < 12 else 5.0))
    gt = PoseTrajectory([p.t_ns for p, _, _, _ in given], np.array(gt_p),
                        np.array([np.eye(3)] * len(given)))
    report = write_run(tmp_path, _Pipeline(h, final), SchedulerReport(), gt, {}, DavioConfig())
    seg_ate = [s["metrics"]["ate_se3_m"] for s in report["segments"]]
    assert max(seg_ate) < 1e-9 and report["metrics"]["ate_se3_m"] == seg_ate[-1]
    assert report["metrics"]["pairs"] == 18
    scope = _last_segment_scope(report)
    assert "over the last segment only (18 of 30 poses: the filter was reset 1x" in scope
    assert "ATE by segment (se3): 0.000 m (12 poses), 0.000 m (18 poses)" in segments_line(report)
    # a last segment too short to score: the earlier segments' ATE is still said
    short = dict(report, segments=[*report["segments"][:1], {"poses": 2, "metrics": {}}], metrics={})
    assert segments_line(short).startswith("ATE by segment (se3): 0.000 m (12 poses), - (2 poses)")
    assert segments_line(dict(report, segments=report["segments"][:1])) == ""


def test_one_segment_across_a_chunk_boundary_writes_no_segment_files(tmp_path) -> None:
    from runtime.pose_history import CHUNK_ROWS

    h, given = _history(np.random.default_rng(2), n=CHUNK_ROWS + 5, restart=None)
    final = [T @ _offset(k) for k, (_, T, _, _) in enumerate(given)]
    report = write_run(tmp_path, _Pipeline(h, final), SchedulerReport(), None, {}, DavioConfig())
    assert not list(tmp_path.glob("*_segment*.tum")) and report["metrics_segment"] == 0
    _same(read_tum(tmp_path / "odometry.tum"), published_trajectory([p for p, _, _, _ in given]))
    t = [p.t_ns for p, _, _, _ in given]
    _same(read_tum(tmp_path / "causal.tum"), _poses(t, [T for _, T, _, _ in given]))
    _same(read_tum(tmp_path / "final.tum"), _poses(t, final))


def _offset(k: int) -> np.ndarray:
    """A correction that differs per pose (so that final.tum cannot pass for causal.tum)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.01 * (k % 7)]).as_matrix()
    T[:3, 3] = [0.1, -0.2 * (k % 3), 0.05]
    return T


def test_a_run_that_published_nothing_writes_empty_files(tmp_path) -> None:
    report = write_run(tmp_path, _Pipeline(PoseHistory(), []), SchedulerReport(), None, {}, DavioConfig())
    assert report["published_poses"] == 0 and report["segments"] == [] and report["metrics_segment"] is None
    assert (tmp_path / "poses.csv").read_text().splitlines()[1:] == []
    for name in ("odometry.tum", "causal.tum", "final.tum"):   # the header line only
        assert [ln for ln in (tmp_path / name).read_text().splitlines() if not ln.startswith("#")] == []
