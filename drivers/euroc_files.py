"""EuRoC / ASL folder files read on their own: the folder (`find_mav0`), `imu0/data.csv`, a camera's
stamps, the state ground truth, a sensor.yaml's rate, and the case-insensitive image-name match.
`drivers.euroc.EurocDriver` replays the whole folder through them."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from drivers.base import IntakeReport, Policy, StreamCounts
from drivers.validation import read_stamped_csv
from runtime.errors import DataError
from runtime.geometry.trajectory import PoseTrajectory

RATE_TOLERANCE = 0.05
"""Relative difference between measured and declared camera rates that is reported as unequal."""

IMU_COLUMNS = "t_ns, wx, wy, wz [rad/s], ax, ay, az [m/s^2]"
CAMERA_COLUMNS = "t_ns, filename"


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp", ".tif", ".tiff")
"""File names in a camera's data folder taken for images (to note those data.csv does not list)."""


class CaseInsensitiveNames:
    """The one file of a folder whose name equals a missing one's but for case (the file name only, not its
    folders; each folder listed once)."""

    def __init__(self) -> None:
        self._folders: dict[Path, dict[str, list[str]]] = {}

    def match(self, path: Path) -> Path | None:
        names = self._folders.get(path.parent)
        if names is None:
            names = {}
            try:
                with os.scandir(path.parent) as entries:
                    for entry in entries:
                        if entry.is_file():
                            names.setdefault(entry.name.lower(), []).append(entry.name)
            except OSError:         # no such folder, or one that cannot be listed: the image stays missing
                names = {}
            self._folders[path.parent] = names
        found = names.get(path.name.lower(), [])
        return path.parent / found[0] if len(found) == 1 else None


def find_mav0(path: str | Path) -> Path:
    """The `mav0` folder of an ASL recording given the sequence folder or `mav0` itself."""
    path = Path(path)
    if not path.is_dir():
        raise DataError("not a directory (expected an EuRoC sequence folder or its mav0)", path)
    if (path / "mav0").is_dir():
        return path / "mav0"
    if (path / "imu0").is_dir() or (path / "cam0").is_dir():
        return path
    raise DataError("no mav0/, imu0/ or cam0/ inside: not an EuRoC/ASL folder", path)


def read_euroc_imu_csv(path: str | Path, policy: Policy = "drop",
                       counts: StreamCounts | None = None,
                       report: IntakeReport | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read an EuRoC `imu0/data.csv`.

    Returns:
        t_ns (N,) int64, gyro (N, 3) rad/s, accel (N, 3) m/s^2 (IMU frame), rows validated under
        `policy` (bad rows dropped and counted in `counts`, or DataError when strict).
    """
    counts = StreamCounts() if counts is None else counts
    rows = read_stamped_csv(path, 6, counts, policy, report=report)
    return rows.t_ns, rows.values[:, 0:3].copy(), rows.values[:, 3:6].copy()


def read_camera_timestamps(path: str | Path, policy: Policy = "drop",
                           counts: StreamCounts | None = None) -> np.ndarray:
    """Camera stamps (N,) int64 ns from a `cam0/data.csv` (t, filename) or a one-stamp-per-line file."""
    counts = StreamCounts() if counts is None else counts
    path = Path(path)
    try:
        with path.open("r", encoding="utf-8-sig") as fh:
            first = next((ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")), "")
    except OSError as exc:
        raise DataError(f"cannot read file: {exc.strerror or exc}", path) from exc
    except UnicodeDecodeError as exc:       # the reader below says the same of the whole file
        raise DataError(f"not a UTF-8 text file (byte {exc.start})", path) from exc
    n_values = 1 if "," in first else 0
    return read_stamped_csv(path, n_values, counts, policy, text=True).t_ns


def _quaternion_check(values: list[float]) -> str | None:
    """Reject a ground-truth row whose quaternion (columns 4-7 after the stamp) is not near unit norm."""
    n = math.sqrt(sum(q * q for q in values[3:7]))
    return None if abs(n - 1.0) < 1e-2 else f"quaternion norm {n:.4f} is not 1"


def read_euroc_groundtruth(path: str | Path, policy: Policy = "drop",
                           counts: StreamCounts | None = None) -> PoseTrajectory:
    """Read an EuRoC state ground-truth CSV (t, p, q_wxyz, v, bg, ba; or t, p, q_wxyz alone, as `davio
    eval` reads it, when the first row has 8 fields) into a PoseTrajectory T_WI.

    Rows whose quaternion is not of unit norm (within 1 %) are counted as malformed.
    """
    from runtime.geometry import quat_wxyz_to_rot

    counts = StreamCounts() if counts is None else counts
    n_values = 7 if _first_row_fields(Path(path)) == 8 else 16
    rows = read_stamped_csv(path, n_values, counts, policy, row_check=_quaternion_check)
    v = rows.values
    R = quat_wxyz_to_rot(v[:, 3:7]) if len(v) else np.zeros((0, 3, 3))
    extra = {} if n_values == 7 else {"v": v[:, 7:10], "bg": v[:, 10:13], "ba": v[:, 13:16]}
    return PoseTrajectory(rows.t_ns, v[:, 0:3], R, meta={"source": str(path)}, **extra)


def _first_row_fields(path: Path) -> int | None:
    """Comma-separated fields of the first data row (None when unreadable: the reader says why)."""
    try:
        with path.open("r", encoding="utf-8-sig") as fh:
            first = next((ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")), "")
    except (OSError, UnicodeDecodeError):
        return None
    return len(first.split(",")) if first else None


def declared_rate_hz(sensor_yaml: Path) -> float | None:
    """`rate_hz` of an ASL sensor.yaml, or None when absent or unreadable (the rig reader reports a
    broken camera file; the size, encoding and nesting limits of `calib.fields.read_yaml` apply)."""
    if not sensor_yaml.is_file():
        return None
    from calib.fields import read_yaml
    from runtime.errors import CalibrationError

    try:
        data = read_yaml(sensor_yaml)
    except CalibrationError:
        return None
    rate = data.get("rate_hz") if isinstance(data, dict) else None
    return float(rate) if isinstance(rate, int | float) and not isinstance(rate, bool) else None
