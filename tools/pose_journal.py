"""The published poses of a run journalled to disk as they are published, so that a run killed at any
moment (power loss, SIGKILL, a crash) keeps its trajectory up to about a second before, beside the map
archive, which is checkpointed at every commit.

`PoseJournal` is an `on_pose` callback: each published pose's T_MI (map frame, with the correction in
effect when it was published: the causal trajectory) is appended to `<run>.partial/causal.journal.tum`, a
TUM file evo reads; the file is flushed at most every `flush_s` seconds (wall clock). When the run ends
normally its outputs are written whole and `close(remove=True)` deletes the journal.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from runtime.geometry.quaternion import rot_to_quat_xyzw
from tools.evaluation.trajectory_io import TUM_HEADER, tum_line

JOURNAL_NAME = "causal.journal.tum"


class PoseJournal:
    """Appends every published pose to `folder / JOURNAL_NAME` (see the module docstring)."""

    def __init__(self, folder: str | Path, flush_s: float = 1.0) -> None:
        self.path = Path(folder) / JOURNAL_NAME
        self.flush_s = float(flush_s)
        self._fh: IO[str] | None = open(self.path, "w", encoding="utf-8")   # noqa: SIM115 - held open
        self._fh.write(TUM_HEADER + "\n")
        self._fh.flush()
        self._last_flush = time.monotonic()
        self.poses = 0

    def __call__(self, pose: Any) -> None:
        """Journal one runtime.session.Pose (its t_ns and T_MI)."""
        if self._fh is None:
            return
        T = pose.T_MI
        self._fh.write(tum_line(pose.t_ns, T[:3, 3], rot_to_quat_xyzw(T[:3, :3])) + "\n")
        self.poses += 1
        now = time.monotonic()
        if now - self._last_flush >= self.flush_s:
            self._fh.flush()
            self._last_flush = now

    def close(self, remove: bool = False) -> None:
        """Flush and close the journal; with `remove`, delete it (the run's own outputs replace it)."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        if remove:
            self.path.unlink(missing_ok=True)


def chain_poses(*callbacks: Callable[[Any], None]) -> Callable[[Any], None]:
    """One `on_pose` callback calling each of `callbacks` in order."""
    def call(pose: Any) -> None:
        for cb in callbacks:
            cb(pose)
    return call
