"""What `davio run` and `davio live` feed while a run goes: the pose journal and events.jsonl in the run
folder, and, when asked for, the live view (`--view`) and the UDP stream (`--stream`). Opened together, so
that one failing to open (a port in use, a full disk) closes those opened before it; closed together."""
from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any


class RunSinks:
    """The run's live outputs (see the module docstring); `on_pose` / `on_event` feed all of them.

    Args:
        folder: the run's folder being written (`RunFolder.path`).
        view_port: `--view`: (host, port), a port, or None (no view).
        stream_url: `--stream` (None: no stream).
        console: one more on_event callback (e.g. `davio live`'s status line), or None.
        view: a live view the caller opened and closes (`davio live` opens it before the device starts:
            viser's import takes 0.7 s); `view_port` is not used then.
    """

    def __init__(self, folder: Path, view_port: tuple[str, int] | int | None, stream_url: str | None,
                 console: Callable[[Any], None] | None = None, view: Any = None) -> None:
        from tools.event_output import EventFile, chain_events
        from tools.live_view import open_view
        from tools.pose_journal import PoseJournal, chain_poses
        from tools.pose_stream import open_stream

        with contextlib.ExitStack() as opened:
            self.stream = open_stream(stream_url)
            if self.stream is not None:
                opened.callback(self.stream.close)
            self.view = view if view is not None else open_view(view_port)
            if self.view is not None and view is None:
                opened.callback(self.view.close)
            self.journal = PoseJournal(folder)
            opened.callback(self.journal.close)
            self.event_file = EventFile(folder)
            opened.callback(self.event_file.close)
            self._close = opened.pop_all()
        self.on_pose = chain_poses(self.journal, None if self.view is None else self.view.on_pose,
                                   None if self.stream is None else self.stream.on_pose)
        self.on_event = chain_events(self.event_file, console,
                                     None if self.stream is None else self.stream.on_event)

    def map_sink(self, sink: Any) -> Any:
        """The map archive's sink, with the view's drawing of each commit when there is a view."""
        return sink if self.view is None else self.view.chain(sink)

    def close(self) -> None:
        """Close every output (idempotent)."""
        self._close.close()

    def warn(self, program: str) -> None:
        """Say on stderr which file stopped during the run (a full or failing disk); the run went on."""
        from tools.event_output import EVENTS_NAME

        for what, failed in (("pose journal", self.journal.failed), (EVENTS_NAME, self.event_file.failed)):
            if failed:
                print(f"{program}: warning: the {what} stopped ({failed}); the run went on", file=sys.stderr)

    def report(self) -> dict:
        """report.json's `view` and `stream` entries."""
        return {"view": None if self.view is None else self.view.report(),
                "stream": None if self.stream is None else self.stream.report()}
