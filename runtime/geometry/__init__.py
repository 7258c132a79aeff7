"""Pure math: SO(3)/SE(3), quaternion conventions, interpolation, trajectories (numba kernels)."""
from __future__ import annotations

from runtime.geometry.trajectory import PoseTrajectory


def kernels_status() -> str:
    """A one-line status of the numba kernels (compiled / cache dir), for `davio info`."""
    import numba

    return f"numba {numba.__version__}, cache dir {numba.config.CACHE_DIR or 'default (__pycache__)'}"


__all__ = ["PoseTrajectory", "kernels_status"]
