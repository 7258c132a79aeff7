"""TUM and EuRoC-CSV trajectory files: exact stamps, round trips, format detection, clear errors."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from runtime.errors import TrajectoryError
from runtime.geometry.trajectory import PoseTrajectory
from tests.conftest import shared_path
from tools.evaluation import (
    detect_format,
    read_euroc_csv,
    read_trajectory,
    read_tum,
    write_euroc_csv,
    write_tum,
)
from tools.evaluation.trajectory_io import ns_to_seconds_text, seconds_text_to_ns


def random_traj(n: int = 30, full: bool = False) -> PoseTrajectory:
    rng = np.random.default_rng(7)
    t = 1_403_715_273_262_142_976 + np.cumsum(rng.integers(1, 10**8, n)).astype(np.int64)
    extra = {"v": rng.normal(size=(n, 3)), "bg": rng.normal(size=(n, 3)), "ba": rng.normal(size=(n, 3))} \
        if full else {}
    return PoseTrajectory(t, rng.normal(size=(n, 3)) * 10, Rotation.random(n, random_state=3).as_matrix(),
                          **extra)


@pytest.mark.parametrize("text, ns", [
    ("1403715529.112143517", 1_403_715_529_112_143_517),
    ("1.403715529112143517e+09", 1_403_715_529_112_143_517),
    ("0.5", 500_000_000), ("-1.25", -1_250_000_000), ("12", 12_000_000_000),
    ("1e-9", 1), ("0.0000000015", 2),  # half-to-even below 1 ns
])
def test_seconds_text_is_exact(text: str, ns: int) -> None:
    assert seconds_text_to_ns(text) == ns
    assert seconds_text_to_ns(ns_to_seconds_text(ns)) == ns


def test_seconds_text_rejects_non_numbers() -> None:
    for bad in ("abc", "nan", "inf", ""):
        with pytest.raises(ValueError):
            seconds_text_to_ns(bad)


def test_tum_round_trip(tmp_path: Path) -> None:
    traj = random_traj()
    write_tum(tmp_path / "a.tum", traj)
    back = read_tum(tmp_path / "a.tum")
    np.testing.assert_array_equal(back.t_ns, traj.t_ns)
    np.testing.assert_array_equal(back.p, traj.p)
    np.testing.assert_allclose(back.R, traj.R, atol=1e-14)
    assert detect_format(tmp_path / "a.tum") == "tum"
    # quaternion order on disk is x y z w (scipy's default)
    row = (tmp_path / "a.tum").read_text().splitlines()[1].split()
    q = Rotation.from_matrix(traj.R[0]).as_quat()
    np.testing.assert_allclose(np.abs([float(x) for x in row[4:8]]), np.abs(q), atol=1e-14)


@pytest.mark.parametrize("full", [False, True])
def test_euroc_round_trip(tmp_path: Path, full: bool) -> None:
    traj = random_traj(full=full)
    write_euroc_csv(tmp_path / "a.csv", traj)
    back = read_trajectory(tmp_path / "a.csv")
    assert back.meta["format"] == "euroc"
    np.testing.assert_array_equal(back.t_ns, traj.t_ns)
    np.testing.assert_array_equal(back.p, traj.p)
    np.testing.assert_allclose(back.R, traj.R, atol=1e-14)
    if full:
        np.testing.assert_array_equal(back.v, traj.v)
        np.testing.assert_array_equal(back.ba, traj.ba)
    else:
        assert back.v is None


def test_reads_real_files_against_numpy() -> None:
    d = shared_path("evo_reference")
    gt = read_euroc_csv(d / "V102_groundtruth.csv")
    raw = np.loadtxt(d / "V102_groundtruth.csv", delimiter=",", skiprows=1)
    assert len(gt) == raw.shape[0] and gt.t_ns[0] == 1_403_715_524_907_143_168
    np.testing.assert_array_equal(gt.p, raw[:, 1:4])
    np.testing.assert_allclose(gt.R, Rotation.from_quat(raw[:, [5, 6, 7, 4]]).as_matrix(), atol=1e-12)
    np.testing.assert_array_equal(gt.bg, raw[:, 11:14])
    est = read_trajectory(d / "V102.txt")
    raw = np.loadtxt(d / "V102.txt")
    assert est.meta["format"] == "tum" and len(est) == raw.shape[0]
    assert est.meta["repeated_stamps"] == int(np.sum(np.diff(raw[:, 0]) == 0)) > 0
    np.testing.assert_allclose(est.t_ns * 1e-9, raw[:, 0], rtol=0, atol=1e-6)
    assert est.t_ns[0] == 1_403_715_529_112_143_517


def test_header_without_hash_and_comments(tmp_path: Path) -> None:
    f = tmp_path / "gt.csv"
    f.write_text("timestamp,px,py,pz,qw,qx,qy,qz\n# a comment\n10,1,2,3,1,0,0,0\n20, 1, 2, 4, 0, 1, 0, 0\n")
    assert detect_format(f) == "euroc"
    traj = read_trajectory(f)
    np.testing.assert_array_equal(traj.t_ns, [10, 20])
    np.testing.assert_allclose(traj.R[1], np.diag([1.0, -1.0, -1.0]))


@pytest.mark.parametrize("header, fmt", [
    ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []",
     None),
    ("#t,px,py,pz,qw,qx,qy,qz", None),
    ("# t x y z qx qy qz qw", "tum"),            # says the TUM order
    ("", "tum"),                                  # says nothing: TUM, the order of a decimal-stamp file
])
def test_a_csv_with_decimal_stamps_is_read_by_its_header(tmp_path: Path, header: str,
                                                         fmt: str | None) -> None:
    f = tmp_path / "gt.csv"
    f.write_text((header + "\n" if header else "") + "1.5,1,2,3,0,0,0,1\n2.5,1,2,4,0,0,0,1\n")
    if fmt is None:   # w first, as EuRoC: reading it as TUM would swap the quaternion silently
        with pytest.raises(TrajectoryError, match="quaternion w, x, y, z .* not integer nanoseconds") as info:
            detect_format(f)
        assert info.value.line == 2
    else:
        assert detect_format(f) == fmt
        np.testing.assert_array_equal(read_trajectory(f).t_ns, [1_500_000_000, 2_500_000_000])


def test_a_first_row_with_a_sign_is_data_not_a_header(tmp_path: Path) -> None:
    f = tmp_path / "gt.csv"
    f.write_text("#h\n-10,0,0,0,1,0,0,0\n20,0,0,0,1,0,0,0\n")
    with pytest.raises(TrajectoryError, match="integer number of nanoseconds") as info:
        read_euroc_csv(f)          # was skipped as a header, one pose lost unsaid
    assert info.value.line == 2


@pytest.mark.parametrize("name, text, line, match", [
    ("a.tum", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n", 2, "7 fields"),
    ("a.tum", "1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n", 2, "unparseable"),
    ("a.tum", "# c\n1.0 0 0 0 0 0 0 1\n2.0 0 inf 0 0 0 0 1\n", 3, "NaN or Inf"),
    ("a.tum", "1.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n", 2, "decreasing"),
    ("a.tum", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 2\n", 2, "quaternion norm"),
    ("a.tum", "1.0.0 0 0 0 0 0 0 1\n", 1, "bad timestamp"),
    ("a.csv", "#h\n10,0,0,0,1,0,0,0\n11.5,0,0,0,1,0,0,0\n", 3, "integer number of nanoseconds"),
    ("a.csv", "#h\n10,0,0,0,1,0,0,0\n20,0,0,0,1,0,0,0,0,0,0,0,0,0,0,0,0\n", 3, "earlier rows had 8"),
    ("a.csv", "#h\n10,0,0,0,1,0,0,0\n20,0,0,0,1,0,0\n", 3, "expected 8"),
])
def test_malformed_files_name_file_and_line(tmp_path: Path, name: str, text: str, line: int,
                                            match: str) -> None:
    f = tmp_path / name
    f.write_text(text)
    with pytest.raises(TrajectoryError, match=match) as info:
        (read_tum if name.endswith(".tum") else read_euroc_csv)(f)
    assert info.value.line == line and info.value.path == str(f)
    assert f"{f}:{line}" in str(info.value)


def test_empty_missing_and_unknown_files(tmp_path: Path) -> None:
    (tmp_path / "empty.txt").write_text("# only a comment\n")
    with pytest.raises(TrajectoryError, match="no poses"):
        read_trajectory(tmp_path / "empty.txt")
    with pytest.raises(TrajectoryError, match="cannot read"):
        read_trajectory(tmp_path / "missing.txt")
    (tmp_path / "odd.txt").write_text("1 2 3\n")
    with pytest.raises(TrajectoryError, match="cannot tell"):
        read_trajectory(tmp_path / "odd.txt")
    with pytest.raises(TrajectoryError, match="unknown trajectory format"):
        read_trajectory(tmp_path / "odd.txt", fmt="kitti")
