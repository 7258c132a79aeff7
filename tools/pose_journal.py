"""The published poses of a run journalled to disk as they are published, so that a run that is killed
(SIGKILL, a crash, power loss) keeps its trajectory beside the map archive, which is checkpointed at every
commit.

`PoseJournal` is an `on_pose` callback: each published pose's T_MI (map frame, with the correction in
effect when it was published: the causal trajectory) is appended to `<run>.partial/causal.journal.tum`, a
TUM file evo reads. The caller's thread only formats and buffers the line; a background thread flushes
the buffer and fsyncs the file every `sync_s` seconds, so a kill loses at most the poses of the last
`sync_s` (power loss included) and no disk wait ever lands on the tracking thread. When the run ends
normally its outputs are written whole and `close(remove=True)` deletes the journal.
"""
from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

from runtime.geometry.quaternion import rot_to_quat_xyzw
from tools.evaluation.trajectory_io import TUM_HEADER, tum_line
from tools.event_output import chain_events

JOURNAL_NAME = "causal.journal.tum"


class PoseJournal:
    """Appends every published pose to `folder / JOURNAL_NAME` (see the module docstring)."""

    def __init__(self, folder: str | Path, sync_s: float = 1.0) -> None:
        self.path = Path(folder) / JOURNAL_NAME
        self.sync_s = float(sync_s)
        self.poses = 0
        self.failed: str | None = None
        """Why the journal stopped (a full or failing disk), or None: the run goes on without it."""
        self._lock = threading.Lock()
        self._fh = open(self.path, "w", encoding="utf-8")   # noqa: SIM115 - held open for the run
        self._fh.write(TUM_HEADER + "\n")
        self._stop = threading.Event()
        self._syncer = threading.Thread(target=self._sync_loop, name="pose-journal", daemon=True)
        self._syncer.start()

    def __call__(self, pose: Any) -> None:
        """Journal one runtime.session.Pose (its t_ns and T_MI)."""
        T = pose.T_MI
        line = tum_line(pose.t_ns, T[:3, 3], rot_to_quat_xyzw(T[:3, :3])) + "\n"
        with self._lock:
            if self._fh.closed:
                return
            try:
                self._fh.write(line)
            except OSError as exc:
                self._give_up(exc)
                return
            self.poses += 1

    def _give_up(self, exc: OSError) -> None:
        """Stop journalling after a write error (the caller holds the lock); the run goes on."""
        self.failed = f"{self.path}: {exc.strerror or exc}"
        try:
            self._fh.close()
        except OSError:
            pass

    def sync(self) -> None:
        """Flush the buffered lines and fsync the file (what the background thread does every sync_s).
        The fsync runs outside the lock, so the thread that publishes poses never waits for the disk."""
        with self._lock:
            if self._fh.closed:
                return
            try:
                self._fh.flush()
            except OSError as exc:
                self._give_up(exc)
                return
            fd = os.dup(self._fh.fileno())   # our own descriptor: a close meanwhile cannot hand it on
        try:
            os.fsync(fd)
        except OSError as exc:   # a failing disk
            if self.failed is None:
                self.failed = f"{self.path}: {exc.strerror or exc}"
        finally:
            os.close(fd)

    def _sync_loop(self) -> None:
        while not self._stop.wait(self.sync_s):
            self.sync()

    def close(self, remove: bool = False) -> None:
        """Stop the background thread, flush and close the journal; with `remove`, delete it (the run's
        own outputs replace it). Idempotent; never raises for a full or failing disk (`failed` says)."""
        self._stop.set()
        try:   # an fsync hung on a failing disk must not hang the run: the thread is a daemon
            if self._syncer.is_alive() and self._syncer is not threading.current_thread():
                self._syncer.join(timeout=max(5.0, 5 * self.sync_s))
        finally:
            with self._lock:
                if not self._fh.closed:
                    try:
                        self._fh.close()
                    except OSError as exc:
                        self.failed = f"{self.path}: {exc.strerror or exc}"
            if remove:
                try:
                    self.path.unlink(missing_ok=True)
                except OSError:
                    pass


def journal_has_poses(folder: str | Path) -> bool:
    """Whether `folder` holds a pose journal with at least one pose (a killed run worth keeping)."""
    path = Path(folder) / JOURNAL_NAME
    try:
        return path.stat().st_size > len(TUM_HEADER) + 1
    except OSError:
        return False


chain_poses = chain_events
"""One `on_pose` callback calling each of `callbacks` (None skipped) in order: the events' own chaining
(tools.event_output.chain_events), as a pose callback is called the same way."""
