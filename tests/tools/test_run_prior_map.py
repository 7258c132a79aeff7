"""End to end: a second session of one place localised in the first one's saved map, live
(`davio run B --prior-map A`) and afterwards (`davio map align B --to A`), against the simulator's truth.

Two recordings are cut from one trajectory (a preset's ground truth written as TUM) at 0 s and 4 s, their
scene built around the whole trajectory (`davio simulate --scene trajectory`): the same room, two start
poses, so two map frames (A starts at rest on the floor, B in flight, with another heading)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tools.cli import main
from tools.evaluation import read_tum


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from drivers.sim import SimConfig, SimRecording
    from tools.evaluation import write_tum

    root = tmp_path_factory.mktemp("prior")
    truth = SimRecording.from_preset(SimConfig(preset="euroc", seconds=16, seed=3)).groundtruth()
    write_tum(root / "gt.tum", truth)
    for name, start in (("A", "0"), ("B", "4")):
        assert main(["simulate", "--trajectory", str(root / "gt.tum"), "--scene", "trajectory", "--start",
                     start, "--seconds", "9", "--no-depth", "--out", str(root / name)]) == 0
    assert main(["run", str(root / "A"), "--emulated", "--out", str(root / "runA")]) == 0
    assert main(["run", str(root / "B"), "--emulated", "--prior-map", str(root / "runA"),
                 "--out", str(root / "runB")]) == 0
    return root


def _T_WM(run: Path, sim: Path) -> np.ndarray:
    """The SE(3) fit of a run's final trajectory to its recording's truth: map frame -> world."""
    from drivers.trajectory_files import read_trajectory
    from tools.evaluation import ate

    r = ate(read_tum(run / "final.tum"), read_trajectory(sim / "mav0/state_groundtruth_estimate0/data.csv"))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = r.alignment.R, r.alignment.t
    return T


def _rms_through_A(path: Path, root: Path) -> float:
    """RMS distance (m) between B's poses in A's map frame, moved into the world by A's own fit, and B's
    truth: no fit of B's poses at all."""
    from drivers.trajectory_files import read_trajectory
    from tools.evaluation.associate import associate

    truth = read_trajectory(root / "B/mav0/state_groundtruth_estimate0/data.csv")
    est, ref = associate(read_tum(path), truth)
    T = _T_WM(root / "runA", root / "A")
    p = est.p @ T[:3, :3].T + T[:3, 3]
    return float(np.sqrt(np.mean(np.sum((p - ref.p) ** 2, axis=1))))


@pytest.mark.slow
def test_a_live_run_is_localised_in_an_earlier_map_and_publishes_in_its_frame(two_sessions, capsys):
    root = two_sessions
    report = json.loads((root / "runB/report.json").read_text())
    pm = report["prior_map"]
    assert pm["localized"] and pm["agreeing_new_views"] >= 3
    assert sorted(pm["files"]) == ["alignment.json", "causal.prior.tum", "final.prior.tum"]
    assert json.loads((root / "runB/alignment.json").read_text())["prior_relative"] == "../runA/map"
    causal_prior = read_tum(root / "runB/causal.prior.tum")
    causal = read_tum(root / "runB/causal.tum")
    assert len(causal_prior) == pm["poses_in_prior_frame"] > 0
    assert np.array_equal(causal_prior.t_ns, causal.t_ns[-len(causal_prior):])   # from localisation on
    assert len(read_tum(root / "runB/final.prior.tum")) == report["published_poses"]
    # B in A's frame against B's truth, through A's own fit only (the frames differ by metres and degrees)
    T_true = np.linalg.inv(_T_WM(root / "runA", root / "A")) @ _T_WM(root / "runB", root / "B")
    assert np.linalg.norm(T_true[:3, 3]) > 0.5
    assert np.allclose(np.array(pm["T_PN"]), T_true, atol=0.1)
    assert _rms_through_A(root / "runB/causal.prior.tum", root) < 0.1
    assert _rms_through_A(root / "runB/final.prior.tum", root) < 0.1
    assert report["pipeline"]["prior_map"]["errors"] == 0
    live = json.loads((root / "runB/alignment.json").read_text())
    assert pm["switches"] == 0 and live["switches"] == 0
    ids = [json.loads((root / r / "map/manifest.json").read_text())["archive_id"] for r in ("runA", "runB")]
    assert [live["prior_id"], live["new_id"]] == ids
    # the same from the two saved maps afterwards, into another file
    assert main(["map", "align", str(root / "runB"), "--to", str(root / "runA"),
                 "--out", str(root / "offline.json")]) == 0
    offline = json.loads((root / "offline.json").read_text())
    assert np.allclose(np.array(offline["T_PN"]), T_true, atol=0.1)
    assert "localised" in capsys.readouterr().out


def test_prior_map_needs_a_map_and_views(two_sessions, tmp_path, capsys):
    root = two_sessions
    assert main(["run", str(root / "B"), "--native-only", "--prior-map", str(root / "runA"),
                 "--out", str(tmp_path / "x")]) != 0
    assert "needs a depth model" in capsys.readouterr().err
    assert main(["run", str(root / "B"), "--emulated", "--prior-map", str(tmp_path / "nothing"),
                 "--out", str(tmp_path / "y")]) != 0
    assert "nothing" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_the_console_line_says_when_a_wrong_lock_was_replaced():
    from tools.run_summary import prior_line as _prior_line

    pm = {"localized": True, "t": [1.0, 2.0, 0.0], "localized_after_s": 3.5, "yaw_deg": 12.0, "agreeing": 9,
          "poses_in_prior_frame": 40, "switches": 0}
    assert "wrong lock" not in _prior_line(pm)
    line = _prior_line({**pm, "switches": 1})
    assert "localised 3.5 s into the run" in line and "a wrong lock was replaced 1x" in line


def test_a_run_localised_before_a_reset_writes_that_segment_in_the_prior_frame(tmp_path):
    """A run localised in segment 0 whose filter was then reset (segment 1 never localised) wrote no
    causal.prior.tum, final.prior.tum or alignment.json: only the last segment was looked at."""
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    from runtime.geometry import PoseTrajectory, make_pose
    from runtime.graph.prior_frame import PriorFrame
    from runtime.graph.relocalize import Alignment
    from tools.run_prior_frame import write_prior_frame
    from tools.run_summary import prior_line

    T_PN = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), np.array([1.0, 2.0, 0.0]))

    class Localised0:                               # the localizer's answers: segment 0 only
        switches: dict = {}
        prior_segment, prior_id = 0, None

        def segment_versions(self):
            return {0: 1}

        def state(self, seg):
            return 1, T_PN, 0

        def T_PN(self, seg):
            return T_PN if seg == 0 else None

        def alignment(self, seg):
            return Alignment(True, "localized", T_PN) if seg == 0 else Alignment(False, "too few views")

    pf = PriorFrame(Localised0(), "runA/map")
    pf.update(3_000_000_000)                        # localised 3 s into segment 0

    def poses(t_s: np.ndarray) -> PoseTrajectory:
        return PoseTrajectory((t_s * 1e9).astype(np.int64), np.c_[t_s, 0 * t_s, 0 * t_s],
                              np.repeat(np.eye(3)[None], len(t_s), axis=0))

    seg0, seg1 = poses(np.arange(1.0, 6.0)), poses(np.arange(7.0, 9.0))
    out = write_prior_frame(tmp_path, SimpleNamespace(prior=pf), [(0, seg0, seg0), (1, seg1, seg1)], 0)
    assert out["segment"] == 0 and out["last_segment"] == 1 and out["localized"]
    assert sorted(out["files"]) == ["alignment.json", "causal.prior.tum", "final.prior.tum"]
    assert json.loads((tmp_path / "alignment.json").read_text())["new_segment"] == 0
    final = read_tum(tmp_path / "final.prior.tum")
    np.testing.assert_allclose(final.p, seg0.p @ T_PN[:3, :3].T + T_PN[:3, 3], atol=1e-9)
    causal = read_tum(tmp_path / "causal.prior.tum")
    assert list(causal.t_ns) == [3_000_000_000, 4_000_000_000, 5_000_000_000]
    assert out["poses_in_prior_frame"] == 3 and out["localized_after_s"] == 3.0
    said = "hold filter segment 0, the last one localised: segment 1, after a reset, was not"
    assert said in prior_line(out)
    # localised in the last segment: its files, as before, and no word of another segment
    (tmp_path / "b").mkdir()
    last = write_prior_frame(tmp_path / "b", SimpleNamespace(prior=pf), [(0, seg0, seg0)], 0)
    assert last["segment"] == 0 and "last_segment" not in last
