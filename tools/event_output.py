"""Where a run's events (runtime.run_events) go: in `davio run`, `davio live` and `davio demo` one JSON line
each in the run folder's `events.jsonl` (`davio calibrate`: `<out stem>.events.jsonl`), written as they
happen, so that a supervisor can follow the file (`tail -f`) and a killed run keeps them; and one console
line each, "at 6.0 s: GYROSCOPE SCALE (tracked features): ...", so that an operator with a module in hand
hears of a gyroscope in deg/s while holding it (`davio calibrate` says them too). Neither ever ends the
run: a failing disk stops the file, a closed stderr stops the lines, and each says why (`failed`,
`error`)."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from runtime.json_out import strict_dumps

EVENTS_NAME = "events.jsonl"


class EventFile:
    """Appends each event to `folder / EVENTS_NAME` as one JSON object (RunEvent.to_json) and flushes it:
    events are a handful a run, so each costs one write on the pipeline's thread, never a disk sync."""

    def __init__(self, folder: str | Path, name: str = EVENTS_NAME) -> None:
        self.path = Path(folder) / name
        self.written = 0
        self.failed: str | None = None
        """Why the file stopped (a full or failing disk), or None: the run goes on without it."""
        self._fh = open(self.path, "w", encoding="utf-8")   # noqa: SIM115 - held open for the run

    def __call__(self, event: Any) -> None:
        if self._fh.closed:
            return
        try:
            self._fh.write(strict_dumps(event.to_json()) + "\n")
            self._fh.flush()
        except OSError as exc:
            self.failed = f"{self.path}: {exc.strerror or exc}"
            self.close()
            return
        self.written += 1

    def close(self) -> None:
        """Close the file (idempotent; never raises)."""
        try:
            self._fh.close()
        except OSError as exc:
            self.failed = self.failed or f"{self.path}: {exc.strerror or exc}"


class EventConsole:
    """Says each event as "at <data time> s: <message>" through `say`. An error in saying one (a closed
    stderr) stops the lines, not the run: `error` holds it."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.say = say
        self.lines = 0          # lines said or tried (a count: a long run's lines are on the console)
        self.error: str | None = None

    def __call__(self, event: Any) -> None:
        if self.error is not None:
            return
        line = f"at {event.t_s:.1f} s: {event.message}"
        self.lines += 1
        try:
            self.say(line)
        except Exception as exc:    # a reporting aid: the summary and events.jsonl still say all
            self.error = f"{type(exc).__name__}: {exc}"


def chain_events(*callbacks: Callable[[Any], None] | None) -> Callable[[Any], None] | None:
    """One callback calling each given one in turn (None skipped; None when none is left): for `on_event`,
    and for `on_pose` (tools.pose_journal.chain_poses)."""
    live = [c for c in callbacks if c is not None]
    if not live:
        return None

    def call(event: Any) -> None:
        for c in live:
            c(event)

    return call
