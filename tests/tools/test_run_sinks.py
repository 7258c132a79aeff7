"""The live outputs of a run (tools.run_sinks): one that fails to open closes those opened before it; poses
and events reach the journal and events.jsonl."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

import tools.event_output
import tools.pose_journal
import tools.pose_stream
from runtime.errors import ConfigError
from runtime.run_events import RunEvent
from tools.run_sinks import RunSinks


def _recorded(monkeypatch, module, name: str) -> list:
    """Every object `module.name(...)` makes, kept in the returned list."""
    made: list = []
    real = getattr(module, name)
    monkeypatch.setattr(module, name, lambda *a: made.append(real(*a)) or made[-1])
    return made


def test_an_output_that_fails_to_open_closes_those_opened_before_it(tmp_path, monkeypatch):
    streams = _recorded(monkeypatch, tools.pose_stream, "open_stream")
    with pytest.raises(ConfigError, match="--view: 0 is not a TCP port"):
        RunSinks(tmp_path, 0, "udp://127.0.0.1:9")          # the stream opens, the view cannot
    assert streams[0]._sock.fileno() == -1                   # closed
    journals = _recorded(monkeypatch, tools.pose_journal, "PoseJournal")

    def full_disk(folder):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(tools.event_output, "EventFile", full_disk)
    with pytest.raises(OSError, match="No space left"):
        RunSinks(tmp_path, None, "udp://127.0.0.1:9")
    assert journals[0]._fh.closed and not journals[0]._syncer.is_alive()
    assert streams[1]._sock.fileno() == -1


def test_poses_and_events_reach_the_journal_and_the_events_file_and_close_is_idempotent(tmp_path):
    said: list = []
    sinks = RunSinks(tmp_path, None, None, console=said.append)
    assert sinks.report() == {"view": None, "stream": None} and sinks.map_sink("archive") == "archive"
    sinks.on_pose(SimpleNamespace(t_ns=2_000_000_000, T_MI=np.eye(4)))
    event = RunEvent(2_000_000_000, 0.0, "publishing", "publishing metric poses (native:static)",
                     {"source": "native:static", "segment": 0})
    sinks.on_event(event)
    sinks.close()
    sinks.close()
    assert sinks.journal._fh.closed and sinks.event_file._fh.closed and said == [event]
    rows = [r for r in (tmp_path / "causal.journal.tum").read_text().splitlines() if not r.startswith("#")]
    assert len(rows) == 1 and float(rows[0].split()[0]) == 2.0
    assert json.loads((tmp_path / "events.jsonl").read_text()) == event.to_json()
