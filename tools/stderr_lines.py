"""Progress and status lines on stderr that never end a run.

A run's stderr can go away while it works: a pipe whose reader stopped (`davio run ... 2>&1 | head`), a
terminal closed or an SSH session dropped. A failed write then raised inside the tracking loop and ended
the run with its outputs unwritten. `say` writes one line; the first failure replaces `sys.stderr` with
a sink that drops what is written (every later line of the run, warnings included, would fail the same
way), and the run goes on to write its outputs.
"""
from __future__ import annotations

import os
import sys
from collections.abc import Callable

_LOST: list[str] = []
"""Why stderr was dropped (empty while it works)."""


def say(text: str, end: str = "\n") -> None:
    """Write `text` + `end` to stderr and flush; a stderr that fails is dropped for the rest of the run."""
    attempt(lambda: (sys.stderr.write(text + end), sys.stderr.flush()))


def attempt(write: Callable[[], object]) -> None:
    """Call `write` (something that writes to stderr, e.g. a rich progress bar's update) unless stderr was
    dropped; a failure drops it for the rest of the run instead of raising."""
    if _LOST:
        return
    try:
        write()
    except (OSError, ValueError) as exc:     # a closed pipe, a hung-up terminal (EIO), a closed file
        drop_stderr(f"{type(exc).__name__}: {exc}")


def drop_stderr(why: str) -> None:
    """Send the rest of stderr to os.devnull (`why`: what failed)."""
    _LOST.append(why)
    try:
        sys.stderr = open(os.devnull, "w", encoding="utf-8")   # noqa: SIM115 - the process's stderr now
    except OSError:
        pass


def stderr_lost() -> str | None:
    """Why stderr was dropped, or None."""
    return _LOST[0] if _LOST else None
