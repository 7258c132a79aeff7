"""A rich Console on stdout that leaves a closed pipe to the `davio` command line.

rich's own answer to a reader that closed the pipe (`davio eval ate ... | head`) is `SystemExit(1)`: an
error exit for what is no error. This console raises BrokenPipeError instead, which `tools.cli` turns into
the quiet exit 141 that every other command gives.
"""
from __future__ import annotations

from typing import Any


def stdout_console() -> Any:
    """A `rich.console.Console` on stdout whose closed pipe raises BrokenPipeError."""
    from rich.console import Console

    class _PipeConsole(Console):
        def on_broken_pipe(self) -> None:
            self.quiet = True
            raise BrokenPipeError(32, "Broken pipe")

    return _PipeConsole()
