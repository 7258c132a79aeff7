"""Surface metrics between a reconstructed and a reference point cloud (metres).

accuracy = mean distance from each reconstructed point to its nearest reference point,
completeness = mean distance from each reference point to its nearest reconstructed point,
precision = fraction of reconstructed points within `threshold` of the reference,
recall = fraction of reference points within `threshold` of the reconstruction,
F-score = 2 P R / (P + R). Nearest neighbours come from scipy's cKDTree.
"""
from __future__ import annotations

import contextlib
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from runtime.errors import DataError


@dataclass(frozen=True)
class SurfaceResult:
    """Surface metrics at one threshold (distances in metres, ratios in [0, 1])."""

    accuracy_m: float
    completeness_m: float
    accuracy_median_m: float
    completeness_median_m: float
    precision: float
    recall: float
    fscore: float
    chamfer_m: float
    threshold_m: float
    n_rec: int
    n_ref: int

    def as_dict(self) -> dict:
        """JSON-ready dict of all fields."""
        return {"metric": "surface", **asdict(self)}


def _as_points(points: np.ndarray, name: str) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DataError(f"{name}: expected (N, 3) points, got shape {pts.shape}")
    finite = np.all(np.isfinite(pts), axis=1)
    pts = pts[finite]
    if pts.shape[0] == 0:
        raise DataError(f"{name}: no finite points")
    return pts


def voxel_downsample(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Centroids of the points in each occupied cubic voxel of side `voxel_m` (N, 3) -> (M, 3)."""
    pts = _as_points(points, "points")
    if voxel_m <= 0:
        raise DataError(f"voxel size must be positive, got {voxel_m}")
    keys = np.floor(pts / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((counts.size, 3))
    np.add.at(sums, inverse, pts)
    return sums / counts[:, None]


def nearest_distances(query: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Distance from each query point to its nearest target point, metres."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(target).query(query, k=1)
    return np.asarray(d, dtype=np.float64)


def surface_metrics(rec: np.ndarray, ref: np.ndarray, threshold_m: float = 0.1,
                    voxel_m: float | None = None) -> SurfaceResult:
    """Accuracy, completeness, precision, recall and F-score of `rec` against `ref`.

    Args:
        rec, ref: (N, 3) and (M, 3) points in one frame, metres (non-finite rows are ignored).
        threshold_m: distance under which a point counts as matched.
        voxel_m: voxel size for downsampling both clouds first (None: use them as they are).
    """
    if not threshold_m > 0:
        raise DataError(f"threshold must be positive, got {threshold_m}")
    rec = _as_points(rec, "reconstruction")
    ref = _as_points(ref, "reference")
    if voxel_m:
        rec, ref = voxel_downsample(rec, voxel_m), voxel_downsample(ref, voxel_m)
    d_rec = nearest_distances(rec, ref)
    d_ref = nearest_distances(ref, rec)
    precision = float(np.mean(d_rec < threshold_m))
    recall = float(np.mean(d_ref < threshold_m))
    f = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    acc, comp = float(d_rec.mean()), float(d_ref.mean())
    return SurfaceResult(acc, comp, float(np.median(d_rec)), float(np.median(d_ref)), precision, recall,
                         f, 0.5 * (acc + comp), float(threshold_m), int(rec.shape[0]), int(ref.shape[0]))


CLOUD_SUFFIXES = (".ply", ".npy", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts")
"""Point cloud files read: PLY and .npy here, the others through open3d (which reads nothing, with a
warning only, from a format it does not know)."""


def read_point_cloud(path: str | Path) -> np.ndarray:
    """(N, 3) float64 points of a .ply (numpy reader), .npy array, or other open3d-readable file."""
    from runtime.file_kind import FOLDER, MISSING, file_problem

    path = Path(path)
    why = file_problem(path)
    if why is not None:
        raise DataError({FOLDER: "is a folder, not a point cloud file",
                         MISSING: "point cloud file does not exist"}.get(why, why), path)
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise DataError(f"unsupported point cloud format {suffix or '(no suffix)'!r}: give "
                        f"{', '.join(CLOUD_SUFFIXES)}", path)
    if suffix == ".ply":
        from tools.evaluation.ply import read_ply_vertices

        pts = read_ply_vertices(path)
    elif suffix == ".npy":
        try:
            pts = np.asarray(np.load(path, allow_pickle=False), dtype=np.float64)
        except (ValueError, TypeError, EOFError, OSError) as exc:
            raise DataError(f"not a numeric numpy array file: {exc}", path) from exc
    else:
        try:
            import open3d as o3d
        except (ImportError, OSError) as exc:
            raise DataError(f"reading {suffix} clouds needs open3d, which cannot be imported ({exc}); "
                            "convert the cloud to .ply or .npy", path) from exc
        with contextlib.redirect_stdout(sys.stderr):    # Open3D's warnings print through sys.stdout
            pts = np.asarray(o3d.io.read_point_cloud(str(path)).points, dtype=np.float64)
    if pts.ndim == 2 and pts.shape[0] and pts.shape[1] > 3:
        raise DataError(f"holds {pts.shape[1]} values per point, expected 3 (x, y, z): save the "
                        "coordinates alone (e.g. array[:, :3] when they come first)", path)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
        raise DataError(f"no points could be read (shape {pts.shape})", path)
    return pts
