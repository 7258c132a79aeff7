"""Our ATE/RPE against evo (dev dependency) on evo's own V102 reference files, API and CLI."""
from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize

from tests.conftest import shared_path
from tools.cli import main
from tools.evaluation import associate, ate, read_trajectory, rpe
from tools.evaluation.associate import match_stamps

evo_metrics = pytest.importorskip("evo.core.metrics")
evo_sync = pytest.importorskip("evo.core.sync")
evo_io = pytest.importorskip("evo.tools.file_interface")


@pytest.fixture(scope="module")
def files() -> tuple[Path, Path]:
    d = shared_path("evo_reference")
    return d / "V102.txt", d / "V102_groundtruth.csv"


@pytest.fixture(scope="module")
def evo_pair(files):
    est, ref = files
    traj_ref = evo_io.read_euroc_csv_trajectory(str(ref))
    traj_est = evo_io.read_tum_trajectory_file(str(est))
    return evo_sync.associate_trajectories(traj_ref, traj_est, max_diff=0.01)  # evo_ape's default


def evo_ape(evo_pair, align: str | None, relation) -> float:
    r, e = evo_pair
    e = copy.deepcopy(e)
    if align is not None:
        e.align(r, correct_scale=align == "sim3")
    m = evo_metrics.APE(relation)
    m.process_data((r, e))
    return float(m.get_statistic(evo_metrics.StatisticsType.rmse))


@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
def test_ate_equals_evo_ape(files, evo_pair, align) -> None:
    est, ref = (read_trajectory(f) for f in files)
    ours = ate(est, ref, align)
    evo_align = None if align == "none" else align
    assert ours.t_ns.size == evo_pair[0].num_poses
    assert ours.rmse == pytest.approx(evo_ape(evo_pair, evo_align, evo_metrics.PoseRelation.translation_part),
                                      abs=1e-6)
    assert ours.rot["rmse"] == pytest.approx(
        evo_ape(evo_pair, evo_align, evo_metrics.PoseRelation.rotation_angle_deg), abs=1e-6)


@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_cli_json_equals_evo_ape(files, evo_pair, capsys, align) -> None:
    est, ref = files
    assert main(["eval", "ate", str(est), str(ref), "--align", align, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["rmse"] == pytest.approx(
        evo_ape(evo_pair, align, evo_metrics.PoseRelation.translation_part), abs=1e-6)
    assert out["alignment"]["method"] == align


def test_cli_posyaw_equals_brute_force_minimum(files, capsys) -> None:
    """evo has no yaw-only alignment: compare with a numerical 4-DoF least-squares minimum."""
    est, ref = files
    assert main(["eval", "ate", str(est), str(ref), "--align", "posyaw", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    e, r = associate(read_trajectory(est), read_trajectory(ref))
    src, dst = e.p, r.p

    def rms(x: np.ndarray) -> float:
        c, s = np.cos(x[0]), np.sin(x[0])
        Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        return float(np.sqrt(np.mean(np.sum((dst - src @ Rz.T - x[1:]) ** 2, axis=1))))

    # coarse yaw grid (translation from a grid-free start at the centroid offset), then a 4-D refinement
    grid = np.linspace(-np.pi, np.pi, 721)
    starts = [np.r_[y, dst.mean(0) - src.mean(0)] for y in grid]
    best = min(starts, key=rms)
    sol = minimize(rms, best, method="Nelder-Mead",
                   options={"xatol": 1e-11, "fatol": 1e-13, "maxiter": 20000})
    assert out["rmse"] == pytest.approx(sol.fun, abs=1e-6)
    assert out["rmse"] <= sol.fun + 1e-12
    assert np.radians(out["alignment"]["yaw_deg"]) == pytest.approx(sol.x[0], abs=1e-5)
    # 4 DoF can never beat 6 DoF on the same pairs
    se3 = ate(read_trajectory(est), read_trajectory(ref), "se3").rmse
    assert out["rmse"] >= se3 - 1e-12


@pytest.mark.parametrize("delta, unit, all_pairs", [(1, "f", False), (10, "f", True), (1.0, "m", False),
                                                    (0.5, "m", True)])
def test_rpe_equals_evo_rpe(files, evo_pair, delta, unit, all_pairs) -> None:
    r, e = evo_pair
    evo_unit = evo_metrics.Unit.frames if unit == "f" else evo_metrics.Unit.meters
    out = {}
    for rel in (evo_metrics.PoseRelation.translation_part, evo_metrics.PoseRelation.rotation_angle_deg):
        m = evo_metrics.RPE(rel, delta, evo_unit, all_pairs=all_pairs)
        m.process_data((r, e))
        out[rel] = (float(m.get_statistic(evo_metrics.StatisticsType.rmse)), len(m.error))
    ours = rpe(*(read_trajectory(f) for f in files), delta=delta, delta_unit=unit, all_pairs=all_pairs)
    rmse, n = out[evo_metrics.PoseRelation.translation_part]
    assert ours.pairs.shape[0] == n
    assert ours.rmse == pytest.approx(rmse, abs=1e-6)
    assert ours.rot["rmse"] == pytest.approx(out[evo_metrics.PoseRelation.rotation_angle_deg][0], abs=1e-6)


def test_cli_rpe_json(files, evo_pair, capsys) -> None:
    r, e = evo_pair
    m = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, 2, evo_metrics.Unit.frames)
    m.process_data((r, e))
    assert main(["eval", "rpe", *map(str, files), "--delta", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["rmse"] == pytest.approx(float(m.get_statistic(evo_metrics.StatisticsType.rmse)), abs=1e-6)


def test_association_matches_evo_on_jittered_stamps() -> None:
    rng = np.random.default_rng(3)
    long_s = np.cumsum(rng.uniform(0.004, 0.006, 400)) + 100.0
    short_s = np.sort(rng.uniform(99.9, 102.2, 120))
    long_ns = np.round(long_s * 1e9).astype(np.int64)
    short_ns = np.round(short_s * 1e9).astype(np.int64)
    i1, i2 = evo_sync.matching_time_indices(short_ns * 1e-9, long_ns * 1e-9, max_diff=0.002)
    j1, j2 = match_stamps(short_ns, long_ns, 2_000_000)
    np.testing.assert_array_equal(j1, i1)
    np.testing.assert_array_equal(j2, i2)


@pytest.mark.parametrize("offset_s", [0.0, -0.0013])
@pytest.mark.parametrize("n_est, n_ref", [(2, 2), (3, 2), (2, 3)])
def test_association_walks_the_trajectory_evo_walks(n_est: int, n_ref: int, offset_s: float) -> None:
    """evo walks the estimate unless the reference has fewer poses (equal lengths included); walking the
    other one pairs other poses when stamps are near each other."""
    from evo.core.trajectory import PoseTrajectory3D

    from runtime.geometry.trajectory import PoseTrajectory

    est_s = np.array([1.000, 1.004, 1.0065])[:n_est]
    ref_s = np.array([1.003, 1.010, 1.0068])[:n_ref]
    ref_s.sort()

    def ours(stamps_s):
        n = len(stamps_s)
        return PoseTrajectory(np.round(stamps_s * 1e9).astype(np.int64), np.arange(3 * n, dtype=float)
                              .reshape(n, 3), np.tile(np.eye(3), (n, 1, 1)))

    def evo(stamps_s):
        n = len(stamps_s)
        return PoseTrajectory3D(np.arange(3 * n, dtype=float).reshape(n, 3),
                                np.tile([1.0, 0, 0, 0], (n, 1)), stamps_s)

    e, r = associate(ours(est_s), ours(ref_s), max_diff_s=0.01, offset_s=offset_s)
    evo_r, evo_e = evo_sync.associate_trajectories(evo(ref_s), evo(est_s), max_diff=0.01, offset_2=offset_s)
    np.testing.assert_allclose(e.p, evo_e.positions_xyz)
    np.testing.assert_allclose(r.p, evo_r.positions_xyz)


def test_cli_table_and_plots(files, tmp_path, capsys) -> None:
    assert main(["eval", "ate", *map(str, files), "--align", "posyaw", "--plot", str(tmp_path),
                 "--save-aligned", str(tmp_path / "aligned.tum")]) == 0
    text = capsys.readouterr().out
    assert "rmse" in text and "posyaw" in text and "798" in text
    assert (tmp_path / "ate_trajectories.png").stat().st_size > 10_000
    assert (tmp_path / "ate_errors.png").stat().st_size > 10_000
    aligned = read_trajectory(tmp_path / "aligned.tum")
    assert len(aligned) == 798


def test_cli_errors_are_reported(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 nan 0 0 0 1\n")
    assert main(["eval", "ate", str(bad), str(bad)]) == 1
    assert f"{bad}:2" in capsys.readouterr().err
    assert main(["eval"]) == 2
