"""How a run stops (tools/run_outcome.py, tools/stderr_lines.py): Ctrl-C, SIGTERM and SIGHUP finish it
once; a second signal, or one while the outputs are written, does not lose them; a stderr that goes away
does not stop the tracking; a map archive that cannot be written stops, not the run."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from tools import stderr_lines
from tools.run_outcome import finish_mapping, finishing, interruptible

REPO = Path(__file__).resolve().parents[2]


def _signal_self(signum: int) -> None:
    os.kill(os.getpid(), signum)
    time.sleep(0.05)          # the handler runs on the main thread at the next bytecode


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_the_first_signal_stops_the_run_a_later_one_is_said_and_ignored(signum: int, capsys) -> None:
    before = signal.getsignal(signum)
    with interruptible():
        with pytest.raises(KeyboardInterrupt):
            _signal_self(signum)
        _signal_self(signum)                 # a second Ctrl-C while the run winds down
        _signal_self(signal.SIGTERM)
    err = capsys.readouterr().err
    assert err.count("still finishing the run") == 1 and "kill -9 stops it at once" in err
    assert signal.getsignal(signum) == before


def test_once_finishing_no_signal_stops_the_outputs(capsys) -> None:
    """SIGTERM (systemd, docker stop) the moment the data ended lost the whole run."""
    with interruptible():
        finishing("writing the run's outputs")
        _signal_self(signal.SIGTERM)
        _signal_self(signal.SIGINT)
    assert "davio: SIGTERM: still writing the run's outputs" in capsys.readouterr().err


def test_a_signal_while_mapping_the_queued_windows_interrupts_the_run_with_its_outputs() -> None:
    def finish():
        raise KeyboardInterrupt

    res = SimpleNamespace(status="complete", reason=None)
    finish_mapping(res, SimpleNamespace(finish_mapping=finish))
    assert res.status == "interrupted" and "while mapping the windows queued" in res.reason
    res = SimpleNamespace(status="interrupted", reason="x")
    finish_mapping(res, SimpleNamespace(finish_mapping=lambda: pytest.fail("not for a stopped run")))


def test_a_stderr_that_fails_is_dropped_not_raised(monkeypatch) -> None:
    class Gone:
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self) -> None:
            pass

    monkeypatch.setattr(stderr_lines, "_LOST", [])
    monkeypatch.setattr(sys, "stderr", Gone())
    stderr_lines.say("  t =    5.0 s")            # a progress line: raised in the tracking loop
    assert stderr_lines.stderr_lost().startswith("BrokenPipeError")
    print("a later warning", file=sys.stderr)      # every later line goes to os.devnull
    stderr_lines.say("more")


@pytest.mark.slow
def test_a_run_whose_stderr_reader_went_away_tracks_to_the_end(small_sim_folder: Path,
                                                               tmp_path: Path) -> None:
    """`davio run ... 2>&1 | head`: the next progress line raised BrokenPipeError in the tracking loop and
    the run ended at once, its outputs unwritten."""
    out = tmp_path / "run"
    read, write = os.pipe()
    os.close(read)                                   # the reader is gone before the first line
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-m", "tools.cli", "run", str(small_sim_folder), "--native-only",
                           "--out", str(out)], cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=write,
                          text=True, timeout=600)
    os.close(write)
    assert proc.returncode == 0, proc.stdout
    assert json.loads((out / "run_status.json").read_text())["status"] == "complete"
    assert json.loads((out / "report.json").read_text())["published_poses"] > 0
    assert "ATE" in proc.stdout


def test_a_signal_while_the_outputs_are_written_keeps_them(small_sim_folder: Path, tmp_path: Path,
                                                            monkeypatch, capsys) -> None:
    """SIGTERM as map.ply is exported: the run raised KeyboardInterrupt there and left a .partial folder
    without trajectories or report."""
    from tools.cli import main
    from tools.run_map import MapOutput

    finish = MapOutput.finish

    def finish_under_sigterm(self):
        _signal_self(signal.SIGTERM)
        return finish(self)

    monkeypatch.setattr(MapOutput, "finish", finish_under_sigterm)
    out = tmp_path / "run"
    assert main(["run", str(small_sim_folder), "--emulated", "--seconds", "4", "--out", str(out)]) == 0
    assert "SIGTERM: still writing the run's outputs" in capsys.readouterr().err
    assert json.loads((out / "run_status.json").read_text())["status"] == "complete"
    assert (out / "odometry.tum").is_file() and (out / "report.json").is_file()


def test_sigterm_interrupts_a_command_from_its_start() -> None:
    """As PID 1 in a container SIGTERM's default does nothing: one that came while the model loaded (before
    the run's own handler) was lost, and docker killed the run 10 s later without its outputs."""
    from tools.cli import _sigterm_interrupts

    before = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with _sigterm_interrupts():
            with pytest.raises(KeyboardInterrupt):
                _signal_self(signal.SIGTERM)
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
        mine = signal.signal(signal.SIGTERM, lambda *a: None)    # a host program's own handler stays
        with _sigterm_interrupts():
            assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
            _signal_self(signal.SIGTERM)
        signal.signal(signal.SIGTERM, mine)
    finally:
        signal.signal(signal.SIGTERM, before)


def test_a_signal_the_process_ignores_stays_ignored() -> None:
    """`nohup davio live ...` set SIGHUP to ignore, and the run's handler replaced it: a dropped SSH session
    stopped the run nohup was meant to keep."""
    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with interruptible():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            _signal_self(signal.SIGHUP)                  # nothing happens
            with pytest.raises(KeyboardInterrupt):
                _signal_self(signal.SIGTERM)             # the others still stop the run
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, before)
