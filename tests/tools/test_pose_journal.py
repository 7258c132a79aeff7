"""PoseJournal: every published pose on disk as it is published (a killed run keeps its trajectory)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tools.evaluation import ate, read_trajectory
from tools.pose_journal import JOURNAL_NAME, PoseJournal, chain_poses, journal_has_poses

REPO = Path(__file__).resolve().parents[2]


def _poses(n: int) -> list[SimpleNamespace]:
    rng = np.random.default_rng(3)
    out = []
    for k in range(n):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        T[:3, 3] = rng.normal(size=3) * 5
        out.append(SimpleNamespace(t_ns=1_403_715_273_262_142_976 + k * 50_000_001, T_MI=T))
    return out


def test_journal_round_trips_and_is_readable_while_open(tmp_path: Path) -> None:
    poses = _poses(20)
    seen = []
    journal = PoseJournal(tmp_path, sync_s=0.05)
    on_pose = chain_poses(journal, seen.append)
    for p in poses[:12]:
        on_pose(p)
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and not journal_has_poses(tmp_path):
        time.sleep(0.02)                               # the background thread syncs every 0.05 s
    time.sleep(0.2)
    mid = read_trajectory(tmp_path / JOURNAL_NAME)   # on disk: a kill now keeps these 12
    assert len(mid) == 12 and len(seen) == 12
    for p in poses[12:]:
        on_pose(p)
    journal.close()
    traj = read_trajectory(tmp_path / JOURNAL_NAME)
    np.testing.assert_array_equal(traj.t_ns, [p.t_ns for p in poses])
    np.testing.assert_allclose(traj.p, [p.T_MI[:3, 3] for p in poses], rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj.R, [p.T_MI[:3, :3] for p in poses], rtol=0, atol=1e-12)
    journal(poses[0])                                  # closed: ignored
    journal.close(remove=True)
    assert not (tmp_path / JOURNAL_NAME).exists() and not journal_has_poses(tmp_path)
    empty = PoseJournal(tmp_path / "", sync_s=10.0)
    empty.close()                                      # a header only: nothing worth keeping
    assert (tmp_path / JOURNAL_NAME).exists() and not journal_has_poses(tmp_path)


def test_a_failure_mid_run_keeps_the_partial_folder_when_poses_were_journalled(tmp_path: Path) -> None:
    from tools.run_folder import RunFolder

    folder = RunFolder.prepare(tmp_path / "run")
    folder.create()
    journal = PoseJournal(folder.path)
    with pytest.raises(RuntimeError), folder.discard_on_error():
        for p in _poses(3):
            journal(p)
        journal.close()
        raise RuntimeError("an unexpected failure mid-run")
    assert len(read_trajectory(folder.path / JOURNAL_NAME)) == 3
    bare = RunFolder.prepare(tmp_path / "bare")
    bare.create()
    with pytest.raises(RuntimeError), bare.discard_on_error():
        PoseJournal(bare.path).close()
        raise RuntimeError("a bad recording, before any pose")
    assert not bare.path.exists()
    # a run event on disk (say, the rig finding that explains the failure) is worth keeping too
    from runtime.run_events import RunEvent
    from tools.event_output import EventFile

    told = RunFolder.prepare(tmp_path / "told")
    told.create()
    with pytest.raises(RuntimeError), told.discard_on_error():
        events = EventFile(told.path)
        events(RunEvent(1, 0.0, "rig_finding", "GYROSCOPE SCALE (tracked features): ...", {}))
        events.close()
        raise RuntimeError("an unexpected failure before any pose")
    assert (told.path / "events.jsonl").stat().st_size > 0


@pytest.mark.slow
def test_a_killed_run_keeps_its_trajectory_in_the_journal(small_sim_folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "killed"
    partial = out.with_name(out.name + ".partial")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "tools.cli", "run", str(small_sim_folder), "--native-only",
           "--out", str(out), "--paced", "--speed", "0.5"]
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    journal = partial / JOURNAL_NAME
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (not journal.exists() or journal.stat().st_size < 2000):
        time.sleep(0.2)   # about 20 poses flushed (each line ~ 100 bytes)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not out.exists() and journal.exists()
    traj = read_trajectory(journal)
    assert len(traj) >= 10 and np.all(np.diff(traj.t_ns) > 0)
    gt = read_trajectory(small_sim_folder / "mav0" / "state_groundtruth_estimate0" / "data.csv")
    assert ate(traj, gt, "posyaw").trans["rmse"] < 0.1   # the poses the robot had, against the truth


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux) to emulate a full disk")
def test_a_full_disk_stops_the_journal_not_the_run(tmp_path: Path) -> None:
    journal = PoseJournal(tmp_path, sync_s=0.01)
    journal._fh.close()
    journal._fh = open("/dev/full", "w", encoding="utf-8")   # every write that reaches the disk fails
    for p in _poses(2000):                                      # more than the write buffer holds
        journal(p)                                              # never raises on the tracking thread
    journal.close()                                             # nor when it flushes the rest
    assert journal.failed is not None and "No space left" in journal.failed
    journal.close(remove=True)
