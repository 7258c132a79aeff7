"""Readers of the trajectory and IMU files the simulator replays (EuRoC ASL CSV, TUM, timestamps).

Stamps are parsed as integers (EuRoC ns) or as decimal strings converted exactly to int64 ns (TUM
seconds), never through float. Quaternions: EuRoC w-first, TUM x y z w (Hamilton) — converted to
rotation matrices here, at the file boundary.
"""

from __future__ import annotations

from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from runtime.errors import DataError, TrajectoryError
from runtime.geometry.quaternion import quat_wxyz_to_rot
from runtime.geometry.trajectory import PoseTrajectory


def _seconds_to_ns(text: str, path: Path, line: int) -> int:
    try:
        return int((Decimal(text) * 1_000_000_000).to_integral_value())
    except InvalidOperation as exc:
        raise TrajectoryError(f"bad time stamp {text!r}", path, line) from exc


def _rows(path: Path, sep: str | None) -> list[tuple[int, list[str]]]:
    path = Path(path)
    if not path.is_file():
        raise DataError("file not found", path)
    out = []
    with path.open() as fh:
        for i, raw in enumerate(fh, start=1):
            text = raw.strip()
            if not text or text.startswith("#") or text[0].isalpha():
                continue
            parts = [p.strip() for p in (text.split(sep) if sep else text.split())]
            out.append((i, [p for p in parts if p != ""]))
    return out


def _finite_floats(parts: list[str], path: Path, line: int, what: type[DataError]) -> np.ndarray:
    try:
        vals = np.array([float(p) for p in parts])
    except ValueError as exc:
        raise what(f"unparseable number in {parts}", path, line) from exc
    if not np.all(np.isfinite(vals)):
        raise what("non-finite value", path, line)
    return vals


def _check_increasing(t: np.ndarray, lines: list[int], path: Path, what: type[DataError]) -> None:
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        raise what("time stamps must increase strictly", path, lines[bad[0] + 1])


def read_euroc_state(path: str | Path) -> PoseTrajectory:
    """EuRoC state_groundtruth_estimate0 CSV (t_ns, p, q_wxyz[, v, bg, ba]) -> PoseTrajectory T_WI."""
    path = Path(path)
    rows = _rows(path, ",")
    if not rows:
        raise TrajectoryError("no data rows", path)
    t, vals, lines = [], [], []
    width = len(rows[0][1])
    if width not in (8, 17):
        raise TrajectoryError(f"expected 8 or 17 columns (EuRoC state), got {width}", path, rows[0][0])
    for line, parts in rows:
        if len(parts) != width:
            raise TrajectoryError(f"expected {width} columns, got {len(parts)}", path, line)
        try:
            t.append(int(parts[0]))
        except ValueError as exc:
            raise TrajectoryError(f"time stamp {parts[0]!r} is not integer nanoseconds", path, line) from exc
        vals.append(_finite_floats(parts[1:], path, line, TrajectoryError))
        lines.append(line)
    t_ns = np.array(t, np.int64)
    _check_increasing(t_ns, lines, path, TrajectoryError)
    V = np.array(vals)
    R = quat_wxyz_to_rot(V[:, 3:7] / np.linalg.norm(V[:, 3:7], axis=1, keepdims=True))
    if width == 17:
        return PoseTrajectory(
            t_ns, V[:, 0:3], R, V[:, 7:10], V[:, 10:13], V[:, 13:16], meta={"source": str(path)}
        )
    return PoseTrajectory(t_ns, V[:, 0:3], R, meta={"source": str(path)})


def read_tum(path: str | Path) -> PoseTrajectory:
    """TUM file (t[s] x y z qx qy qz qw) -> PoseTrajectory."""
    path = Path(path)
    rows = _rows(path, None)
    if not rows:
        raise TrajectoryError("no data rows", path)
    t, vals, lines = [], [], []
    for line, parts in rows:
        if len(parts) != 8:
            raise TrajectoryError(f"expected 8 columns (TUM), got {len(parts)}", path, line)
        t.append(_seconds_to_ns(parts[0], path, line))
        vals.append(_finite_floats(parts[1:], path, line, TrajectoryError))
        lines.append(line)
    t_ns = np.array(t, np.int64)
    _check_increasing(t_ns, lines, path, TrajectoryError)
    V = np.array(vals)
    q = V[:, [6, 3, 4, 5]]
    R = quat_wxyz_to_rot(q / np.linalg.norm(q, axis=1, keepdims=True))
    return PoseTrajectory(t_ns, V[:, 0:3], R, meta={"source": str(path)})


def read_trajectory(path: str | Path) -> PoseTrajectory:
    """Read a EuRoC state CSV (comma separated) or a TUM file (whitespace separated)."""
    path = Path(path)
    if not path.is_file():
        raise TrajectoryError("trajectory file not found", path)
    with path.open() as fh:
        for raw in fh:
            text = raw.strip()
            if text and not text.startswith("#"):
                return read_euroc_state(path) if "," in text else read_tum(path)
    raise TrajectoryError("no data rows", path)


def read_imu_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EuRoC imu0 CSV (t_ns, gyro xyz rad/s, accel xyz m/s^2) -> (t_ns (N,), gyro (N,3), accel (N,3))."""
    path = Path(path)
    rows = _rows(path, ",")
    if not rows:
        raise DataError("no IMU rows", path)
    t, vals, lines = [], [], []
    for line, parts in rows:
        if len(parts) != 7:
            raise DataError(f"expected 7 columns (EuRoC imu0), got {len(parts)}", path, line)
        try:
            t.append(int(parts[0]))
        except ValueError as exc:
            raise DataError(f"time stamp {parts[0]!r} is not integer nanoseconds", path, line) from exc
        vals.append(_finite_floats(parts[1:], path, line, DataError))
        lines.append(line)
    t_ns = np.array(t, np.int64)
    _check_increasing(t_ns, lines, path, DataError)
    V = np.array(vals)
    return t_ns, V[:, 0:3], V[:, 3:6]


def read_timestamps(path: str | Path) -> np.ndarray:
    """One int64 ns stamp per line (e.g. cam0_timestamps.txt), strictly increasing."""
    path = Path(path)
    rows = _rows(path, ",")
    t, lines = [], []
    for line, parts in rows:
        try:
            t.append(int(parts[0]))
        except ValueError as exc:
            raise DataError(f"time stamp {parts[0]!r} is not integer nanoseconds", path, line) from exc
        lines.append(line)
    t_ns = np.array(t, np.int64)
    _check_increasing(t_ns, lines, path, DataError)
    return t_ns
