"""Trajectory files for evaluation: the readers (drivers.trajectory_files) and the TUM / EuRoC writers.

Written stamps are exact decimal seconds (TUM, 9 digits) or integer nanoseconds (EuRoC); floats are
written so that they read back exactly. Files are replaced atomically.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.trajectory_files import (
    detect_format,
    ns_to_seconds_text,
    read_euroc_csv,
    read_trajectory,
    read_tum,
    seconds_text_to_ns,
)
from runtime.files import atomic_write_text
from runtime.geometry import rot_to_quat_wxyz, rot_to_quat_xyzw
from runtime.geometry.trajectory import PoseTrajectory

__all__ = ["atomic_write_text", "detect_format", "ns_to_seconds_text", "read_euroc_csv", "read_trajectory",
           "read_tum", "seconds_text_to_ns", "write_euroc_csv", "write_tum"]


def _num(x: float) -> str:
    return repr(float(x))


TUM_HEADER = "# t[s] x y z qx qy qz qw"


def tum_line(t_ns: int, p: np.ndarray, q_xyzw: np.ndarray) -> str:
    """One TUM line: the stamp in seconds with 9 decimals (exact), position and quaternion (x y z w)."""
    return " ".join([ns_to_seconds_text(int(t_ns))] + [_num(x) for x in p] + [_num(x) for x in q_xyzw])


def write_tum(path: str | Path, traj: PoseTrajectory) -> None:
    """Write poses T_WB as TUM lines (stamps with 9 decimals, exact; floats round-trip exactly)."""
    q = rot_to_quat_xyzw(traj.R) if len(traj) else np.zeros((0, 4))
    rows = [TUM_HEADER] + [tum_line(int(traj.t_ns[k]), traj.p[k], q[k]) for k in range(len(traj))]
    atomic_write_text(Path(path), "\n".join(rows) + "\n")


def write_euroc_csv(path: str | Path, traj: PoseTrajectory) -> None:
    """Write an EuRoC state CSV (t[ns], p, q wxyz, and v, bg, ba when all three are present)."""
    q = rot_to_quat_wxyz(traj.R) if len(traj) else np.zeros((0, 4))
    full = traj.v is not None and traj.bg is not None and traj.ba is not None
    header = "#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []"
    if full:
        header += (",v_x [m s^-1],v_y [m s^-1],v_z [m s^-1],bg_x [rad s^-1],bg_y [rad s^-1],bg_z [rad s^-1],"
                   "ba_x [m s^-2],ba_y [m s^-2],ba_z [m s^-2]")
    rows = [header]
    for k in range(len(traj)):
        parts = [str(int(traj.t_ns[k]))] + [_num(x) for x in traj.p[k]] + [_num(x) for x in q[k]]
        if full:
            parts += [_num(x) for x in (*traj.v[k], *traj.bg[k], *traj.ba[k])]
        rows.append(",".join(parts))
    atomic_write_text(Path(path), "\n".join(rows) + "\n")
