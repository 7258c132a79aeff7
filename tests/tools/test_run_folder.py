"""Run folders: --out checked before the work, whole runs renamed into place, interrupted runs kept and
marked, killed runs recognisable (a kill at a random moment never leaves a folder that reads as
complete)."""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from runtime.errors import ConfigError
from tools.run_folder import RunFolder, run_status

REPO = Path(__file__).resolve().parents[2]


def test_out_that_cannot_be_a_folder_is_refused_before_the_work(tmp_path: Path, monkeypatch) -> None:
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(ConfigError, match="is a file, not a folder"):
        RunFolder.prepare(f)
    with pytest.raises(ConfigError, match="is a file, so no folder can be made under it"):
        RunFolder.prepare(f / "sub" / "run")
    monkeypatch.setattr(os, "access", lambda p, mode: False)   # (CI runs as root: permissions never bite)
    with pytest.raises(ConfigError, match="is not writable"):
        RunFolder.prepare(tmp_path / "new")
    assert not (tmp_path / "new").exists() and not (tmp_path / "new.partial").exists()


def test_non_empty_folders_need_overwrite_and_only_runs_are_replaced(tmp_path: Path) -> None:
    other = tmp_path / "photos"
    other.mkdir()
    (other / "a.jpg").write_text("x")
    with pytest.raises(ConfigError, match="not empty"):
        RunFolder.prepare(other)
    with pytest.raises(ConfigError, match="holds no readable run_status.json"):
        RunFolder.prepare(other, overwrite=True)
    assert (other / "a.jpg").exists()
    (other / "report.json").write_text("{}")      # a generic name is no proof of a DAVIO run
    (other / "odometry.tum").write_text("")
    with pytest.raises(ConfigError, match="holds no readable run_status.json"):
        RunFolder.prepare(other, overwrite=True)
    (other / "run_status.json").write_text('{"status": "complete"}')   # not one a run wrote: no file list
    with pytest.raises(ConfigError, match="is not one a DAVIO run wrote"):
        RunFolder.prepare(other, overwrite=True)

    out = tmp_path / "run"
    first = RunFolder.prepare(out)
    first.create()
    (first.path / "odometry.tum").write_text("# first\n")
    (first.path / "only_in_first.txt").write_text("x")
    assert not out.exists()                       # nothing lands before the run ends
    assert first.finish("complete") == out and run_status(out) == "complete"
    with pytest.raises(ConfigError, match="--overwrite"):
        RunFolder.prepare(out)
    second = RunFolder.prepare(out, overwrite=True)
    second.create()
    (second.path / "odometry.tum").write_text("# second\n")
    assert (out / "only_in_first.txt").exists()   # the previous run stays until the new one ends
    second.finish("interrupted", "Ctrl-C")
    assert not (out / "only_in_first.txt").exists() and (out / "odometry.tum").read_text() == "# second\n"
    status = json.loads((out / "run_status.json").read_text())
    assert status["status"] == "interrupted" and status["files"] == ["odometry.tum"]
    assert not list(tmp_path.glob("run.*"))       # no partial or old folder left behind
    # the run's own map exports may be there; a file the user put in the run folder may not
    (out / "map.png").write_text("png")
    (out / "causal.earlier-prior.tum").write_text("")   # what `map align --overwrite` keeps aside
    (out / ".DS_Store").write_text("finder")      # what file browsers add is no user data
    (out / "._odometry.tum").write_text("exfat")
    assert RunFolder.prepare(out, overwrite=True).replace_existing
    (out / "notes").mkdir()
    (out / "notes" / "thesis.tex").write_text("mine")
    with pytest.raises(ConfigError, match=r"holds files the run did not write \(notes/thesis.tex\)"):
        RunFolder.prepare(out, overwrite=True)


def test_a_folder_holding_only_os_metadata_counts_as_empty(tmp_path: Path) -> None:
    out = tmp_path / "new_in_finder"
    out.mkdir()
    (out / ".DS_Store").write_text("finder")
    folder = RunFolder.prepare(out)                            # no --overwrite needed
    folder.create()
    (folder.path / "odometry.tum").write_text("#\n")
    assert folder.finish("complete") == out and sorted(p.name for p in out.iterdir()) == [
        "odometry.tum", "run_status.json"]


def test_a_leftover_partial_is_removed_only_when_a_run_wrote_it(tmp_path: Path) -> None:
    out = tmp_path / "data"
    partial = tmp_path / "data.partial"
    (partial / "map").mkdir(parents=True)
    for name in ("odometry.tum", "report.json", "map/manifest.json", "map/submap_000003.npz",
                 "map/.submap_000004.npz.abc.tmp"):
        (partial / name).write_text("x")
    with pytest.raises(ConfigError, match="unfinished run"):
        RunFolder.prepare(out)
    (partial / "map" / ".DS_Store").write_text("finder")
    RunFolder.prepare(out, overwrite=True).create()           # a killed run's leftovers go
    assert partial.is_dir() and not any(partial.iterdir())
    (partial / "experiment.csv").write_text("mine")           # someone else's folder of that name
    with pytest.raises(ConfigError, match=r"holds files no DAVIO run writes \(experiment.csv\)"):
        RunFolder.prepare(out, overwrite=True)
    assert (partial / "experiment.csv").read_text() == "mine"


def _run_cmd(rec: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "tools.cli", "run", str(rec), "--native-only", "--out", str(out)]


@pytest.mark.slow
def test_a_kill_at_a_random_moment_never_leaves_a_folder_that_reads_as_complete(
        small_sim_folder: Path, tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    rng = random.Random()   # a different moment each run; printed on failure
    for k in range(2):
        out = tmp_path / f"killed{k}"
        delay = rng.uniform(1.0, 8.0)
        proc = subprocess.Popen(_run_cmd(small_sim_folder, out), cwd=REPO, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(delay)
        proc.kill()
        proc.wait()
        partial = out.with_name(out.name + ".partial")
        msg = f"killed after {delay:.2f} s"
        if out.exists():   # the run had ended: whole, and says so
            assert run_status(out) == "complete", msg
            assert not partial.exists(), msg
        else:
            assert run_status(partial) == "unfinished", msg
        # the next run into the same --out needs --overwrite only when a partial run is left
        if partial.exists():
            r = subprocess.run(_run_cmd(small_sim_folder, out), cwd=REPO, env=env, capture_output=True,
                               text=True)
            assert r.returncode == 1 and "unfinished run" in r.stderr, msg


@pytest.mark.slow
def test_sigint_keeps_the_outputs_and_marks_them_interrupted(small_sim_folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "interrupted"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    # paced at half speed: the 6 s recording takes 12 s, so the signal lands well inside it even when the
    # machine is slow (at full speed a late start left 2 s between the signal and the recording's end)
    proc = subprocess.Popen(_run_cmd(small_sim_folder, out) + ["--paced", "--speed", "0.5"], cwd=REPO,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    partial = out.with_name(out.name + ".partial")
    events = partial / "events.jsonl"
    deadline = time.monotonic() + 300
    # the signal once a filter publishes (its event is flushed to disk as it happens), whatever the time the
    # process took to start on a loaded machine: then about 8 s of the recording's 12 s are left
    try:
        while not (events.exists() and '"publishing"' in events.read_text()):
            assert proc.poll() is None, f"the run ended before publishing: {proc.communicate()[1]}"
            assert time.monotonic() < deadline, "no publishing event within 300 s"
            time.sleep(0.2)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert run_status(out) == "interrupted" and not partial.exists()
    rows = [ln for ln in (out / "odometry.tum").read_text().splitlines() if not ln.startswith("#")]
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "interrupted" and len(rows) == report["published_poses"] > 0
    umask = os.umask(0)
    os.umask(umask)
    for f in ("report.json", "odometry.tum", "run_status.json"):   # the usual permissions, not mkstemp's 0600
        assert (out / f).stat().st_mode & 0o777 == 0o666 & ~umask, f


def test_a_rig_file_without_intrinsics_is_named_not_the_recording(small_sim_folder: Path, tmp_path: Path,
                                                                  capsys) -> None:
    """--rig whose cam0.intrinsics is null: the error names that file and key, not the recording's
    sensor.yaml (which exists)."""
    from calib import Rig, write_kalibr
    from tools.cli import main

    rig = tmp_path / "withheld.yaml"
    write_kalibr(Rig(None, None, None, None, None, "withheld"), rig)
    assert main(["run", str(small_sim_folder), "--rig", str(rig), "--native-only", "--out",
                 str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert f"--rig {rig}: holds no camera intrinsics" in err and "sensor.yaml" not in err
