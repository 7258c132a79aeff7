"""Surface metrics against brute-force numpy and a closed-form two-plane case; PLY via open3d; CLI."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from runtime.errors import DataError
from tools.cli import main
from tools.evaluation import read_point_cloud, surface_metrics, voxel_downsample


def brute_nn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)).min(axis=1)


def test_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    ref = rng.uniform(-1, 1, size=(400, 3))
    rec = np.concatenate([ref[:300] + rng.normal(scale=0.03, size=(300, 3)), rng.uniform(-2, 2, (80, 3))])
    res = surface_metrics(rec, ref, threshold_m=0.05)
    d_rec, d_ref = brute_nn(rec, ref), brute_nn(ref, rec)
    assert res.accuracy_m == pytest.approx(d_rec.mean(), rel=1e-12)
    assert res.completeness_m == pytest.approx(d_ref.mean(), rel=1e-12)
    assert res.accuracy_median_m == pytest.approx(np.median(d_rec), rel=1e-12)
    p, r = np.mean(d_rec < 0.05), np.mean(d_ref < 0.05)
    assert res.precision == p and res.recall == r
    assert res.fscore == pytest.approx(2 * p * r / (p + r))
    assert (res.n_rec, res.n_ref) == (380, 400)


@pytest.mark.parametrize("d, thr", [(0.04, 0.1), (0.15, 0.1)])
def test_parallel_planes_closed_form(d: float, thr: float) -> None:
    """Two identical grids on planes z = 0 and z = d: every nearest distance equals d."""
    g = np.stack(np.meshgrid(np.arange(20) * 0.5, np.arange(20) * 0.5), -1).reshape(-1, 2)
    ref = np.c_[g, np.zeros(len(g))]
    rec = np.c_[g, np.full(len(g), d)]
    res = surface_metrics(rec, ref, threshold_m=thr)
    assert res.accuracy_m == pytest.approx(d) and res.completeness_m == pytest.approx(d)
    assert res.chamfer_m == pytest.approx(d)
    expected = 1.0 if d < thr else 0.0
    assert res.precision == expected and res.recall == expected and res.fscore == expected


def test_partial_reconstruction_lowers_recall_only() -> None:
    g = np.stack(np.meshgrid(np.arange(10) * 0.1, np.arange(10) * 0.1), -1).reshape(-1, 2)
    ref = np.c_[g, np.zeros(100)]
    rec = ref[ref[:, 0] < 0.45]                                    # half of the surface, exact
    res = surface_metrics(rec, ref, threshold_m=0.01)
    assert res.precision == 1.0 and res.accuracy_m == 0.0
    assert res.recall == pytest.approx(0.5)
    assert res.fscore == pytest.approx(2 / 3)


def test_voxel_downsample_centroids() -> None:
    pts = np.array([[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [0.11, 0.0, 0.0], [-0.01, 0, 0],
                    [np.nan, 0, 0]])
    out = voxel_downsample(pts, 0.05)
    expected = {(0.02, 0.02, 0.02), (0.11, 0.0, 0.0), (-0.01, 0.0, 0.0)}
    assert {tuple(np.round(p, 12)) for p in out} == expected
    with pytest.raises(DataError):
        voxel_downsample(pts, 0.0)


def test_bad_inputs() -> None:
    with pytest.raises(DataError, match="expected"):
        surface_metrics(np.zeros((5, 2)), np.zeros((5, 3)))
    with pytest.raises(DataError, match="no finite"):
        surface_metrics(np.full((5, 3), np.nan), np.zeros((5, 3)))
    with pytest.raises(DataError, match="threshold"):
        surface_metrics(np.zeros((5, 3)), np.zeros((5, 3)), threshold_m=0)


def write_ply(path: Path, pts: np.ndarray, fmt: str) -> None:
    """A PLY writer independent of the reader: vertices with an extra colour, then one face."""
    head = (f"ply\nformat {fmt} 1.0\ncomment test\nelement vertex {len(pts)}\nproperty double x\n"
            "property double y\nproperty float z\nproperty uchar red\nelement face 1\n"
            "property list uchar int vertex_indices\nend_header\n")
    if fmt == "ascii":
        rows = [f"{float(x)!r} {float(y)!r} {float(np.float32(z))!r} 7\n" for x, y, z in pts]
        body = "".join(rows) + "3 0 1 2\n"
        path.write_text(head + body)
        return
    order = "<" if fmt == "binary_little_endian" else ">"
    dt = np.dtype([("x", order + "f8"), ("y", order + "f8"), ("z", order + "f4"), ("r", "u1")])
    rec = np.zeros(len(pts), dt)
    rec["x"], rec["y"], rec["z"], rec["r"] = pts[:, 0], pts[:, 1], pts[:, 2], 7
    path.write_bytes(head.encode() + rec.tobytes() + b"\x03" + np.array([0, 1, 2], order + "i4").tobytes())


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_reader(tmp_path: Path, fmt: str) -> None:
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(50, 3))
    write_ply(tmp_path / "c.ply", pts, fmt)
    got = read_point_cloud(tmp_path / "c.ply")
    np.testing.assert_array_equal(got[:, :2], pts[:, :2])
    np.testing.assert_array_equal(got[:, 2], pts[:, 2].astype(np.float32))


def test_ply_errors(tmp_path: Path) -> None:
    write_ply(tmp_path / "c.ply", np.zeros((10, 3)), "binary_little_endian")
    data = (tmp_path / "c.ply").read_bytes()
    (tmp_path / "short.ply").write_bytes(data[: len(data) - 60])
    with pytest.raises(DataError, match="truncated"):
        read_point_cloud(tmp_path / "short.ply")
    (tmp_path / "text.ply").write_text("hello\n")
    with pytest.raises(DataError, match="not a PLY"):
        read_point_cloud(tmp_path / "text.ply")
    (tmp_path / "empty.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\n"
                                        "property float y\nproperty float z\nend_header\n")
    with pytest.raises(DataError, match="no points"):
        read_point_cloud(tmp_path / "empty.ply")
    with pytest.raises(DataError, match="does not exist"):
        read_point_cloud(tmp_path / "nope.ply")


def test_cli_json_and_table(tmp_path: Path, capsys) -> None:
    g = np.stack(np.meshgrid(np.arange(15) * 0.2, np.arange(15) * 0.2), -1).reshape(-1, 2)
    ref = np.c_[g, np.zeros(len(g))]
    rec = np.c_[g, np.full(len(g), 0.03)]
    write_ply(tmp_path / "rec.ply", rec, "binary_little_endian")
    np.save(tmp_path / "ref.npy", ref)
    argv = ["eval", "surface", str(tmp_path / "rec.ply"), str(tmp_path / "ref.npy"), "--threshold", "0.05"]
    assert main([*argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["accuracy_m"] == pytest.approx(0.03, abs=1e-7) and out["fscore"] == 1.0
    assert main(argv) == 0
    assert "F-score" in capsys.readouterr().out


def test_align_with_moves_the_cloud_into_the_reference_frame(tmp_path: Path, capsys) -> None:
    """A map in the run's frame M against a reference in the world frame W: the clouds differ by the same
    rigid motion as the trajectories; --align-with recovers it from the trajectories (closed form)."""
    from scipy.spatial.transform import Rotation

    from runtime.geometry import PoseTrajectory
    from tools.evaluation import write_tum

    rng = np.random.default_rng(5)
    R_WM = Rotation.from_euler("z", 37, degrees=True).as_matrix()
    t_WM = np.array([2.0, -1.0, 0.3])
    ref = rng.uniform(-3, 3, size=(3000, 3))                         # the scene, W
    rec = (ref - t_WM) @ R_WM                                        # the same surface, M
    n = 50
    t_ns = 1_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    p_W = np.c_[np.cos(np.arange(n) / 8), np.sin(np.arange(n) / 8), 0.1 * np.arange(n) / n] * 2
    R_W = Rotation.from_euler("z", np.arange(n)[:, None] * 3.0, degrees=True).as_matrix()
    write_tum(tmp_path / "gt.tum", PoseTrajectory(t_ns, p_W, R_W))
    write_tum(tmp_path / "final.tum", PoseTrajectory(t_ns, (p_W - t_WM) @ R_WM, np.einsum("ji,njk->nik",
                                                                                           R_WM, R_W)))
    np.save(tmp_path / "map.npy", rec)
    np.save(tmp_path / "scene.npy", ref)
    args = ["eval", "surface", str(tmp_path / "map.npy"), str(tmp_path / "scene.npy"), "--json"]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["fscore"] < 0.5          # different frames: meaningless
    assert main(args + ["--align-with", str(tmp_path / "final.tum"), str(tmp_path / "gt.tum")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["fscore"] == 1.0 and out["accuracy_m"] < 1e-6
    np.testing.assert_allclose(out["alignment"]["rotation"], R_WM, atol=1e-9)
    np.testing.assert_allclose(out["alignment"]["translation_m"], t_WM, atol=1e-9)
    assert out["repeated_stamps"] == {"est": 0, "ref": 0}
    # the trajectories are read as `eval ate` reads them: a repeated stamp is said, not kept silently
    rows = (tmp_path / "final.tum").read_text().splitlines()
    (tmp_path / "final_repeated.tum").write_text("\n".join(rows[:5] + rows[4:]) + "\n")
    assert main(args + ["--align-with", str(tmp_path / "final_repeated.tum"), str(tmp_path / "gt.tum")]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["repeated_stamps"] == {"est": 1, "ref": 0}
    assert "final_repeated.tum: 1 pose repeats the stamp before" in captured.err


def test_open3ds_warnings_go_to_stderr(tmp_path: Path, capsys) -> None:
    """Open3D prints its warnings through Python's sys.stdout, which a --json command keeps for its JSON."""
    pytest.importorskip("open3d")
    cloud = tmp_path / "cloud.pcd"              # a format open3d reads: it warns and reads nothing
    cloud.write_text("not a cloud\n")
    with pytest.raises(DataError, match="no points could be read"):
        read_point_cloud(cloud)
    captured = capsys.readouterr()
    assert "Open3D" not in captured.out and "Open3D WARNING" in captured.err
