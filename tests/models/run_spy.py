"""RunSpy: stands in for a model's ONNX Runtime session, runs the real one and keeps the RunOptions each run
was given (the tests check that every model runs quietly: models.providers.quiet_run_options)."""
from __future__ import annotations

from typing import Any


class RunSpy:
    def __init__(self, session: Any) -> None:
        self.session = session
        self.log_levels: list[int | None] = []
        """Each run's RunOptions.log_severity_level, None for a run without options."""

    def run(self, names, feeds, options=None):
        self.log_levels.append(None if options is None else options.log_severity_level)
        return self.session.run(names, feeds, options)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.session, name)
