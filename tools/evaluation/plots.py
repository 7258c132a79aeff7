"""Plots of evaluated trajectories and their errors (matplotlib, Agg backend, PNG files)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from runtime.geometry.trajectory import PoseTrajectory


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_trajectories(path: str | Path, ref: PoseTrajectory, est: PoseTrajectory, title: str = "") -> Path:
    """Top view (x-y) and height over time of the reference and the (aligned) estimate; returns the file."""
    plt = _pyplot()
    fig, (ax_xy, ax_z) = plt.subplots(1, 2, figsize=(11, 4.5))
    ax_xy.plot(ref.p[:, 0], ref.p[:, 1], "k--", lw=1, label="reference")
    ax_xy.plot(est.p[:, 0], est.p[:, 1], "C0", lw=1.2, label="estimate")
    ax_xy.set_xlabel("x [m]")
    ax_xy.set_ylabel("y [m]")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.legend()
    t0 = ref.t_ns[0] if len(ref) else 0
    ax_z.plot((ref.t_ns - t0) * 1e-9, ref.p[:, 2], "k--", lw=1, label="reference")
    ax_z.plot((est.t_ns - t0) * 1e-9, est.p[:, 2], "C0", lw=1.2, label="estimate")
    ax_z.set_xlabel("t [s]")
    ax_z.set_ylabel("z [m]")
    fig.suptitle(title)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_errors(path: str | Path, t_ns: np.ndarray, errors: np.ndarray, unit: str, title: str = "") -> Path:
    """Error over time with its RMSE line; returns the file."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 3.5))
    t = (np.asarray(t_ns) - (t_ns[0] if len(t_ns) else 0)) * 1e-9
    ax.plot(t, errors, "C3", lw=1)
    rmse = float(np.sqrt(np.mean(np.square(errors)))) if len(errors) else 0.0
    ax.axhline(rmse, color="k", ls=":", label=f"rmse {rmse:.4g} {unit}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"error [{unit}]")
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
