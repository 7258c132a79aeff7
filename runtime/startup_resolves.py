"""When a start-up window refused for too short a span is re-solved over a longer one, and when those
re-solves end (runtime.ffinit.extension does the solving; runtime.startup.StartupManager the routing)."""
from __future__ import annotations

from typing import Any


class ReSolves:
    """The re-solves of the newest refused window: its ExtensionSeed, the newest frame of the last try,
    and the counters in the start-up report (ff_extensions, ff_extension_expired, and the reasons they
    were given up in ff_extension_rejections).

    Args:
        extend_s: re-solve while the newest frame is at most this many seconds past the window's last
            image (0: never keep a seed).
        spacing_s: a re-solve is due each time the newest frame is this far past the previous try; the
            newer frames of a try are spaced by it too.
        report: the StartupReport the counters go to.
    """

    def __init__(self, extend_s: float, spacing_s: float, report: Any) -> None:
        self.extend_ns = extend_s * 1e9
        self.spacing_ns = spacing_s * 1e9
        self.report = report
        self.seed: Any = None
        self._tried_ns = 0

    def keep(self, seed: Any, from_model_window: bool) -> None:
        """Re-solve `seed` (the refusal of a model window, or of a re-solve that a longer span may cure)."""
        if self.extend_ns <= 0:
            return
        if from_model_window:   # the first re-solve waits one spacing after the window
            self._tried_ns = seed.last_ns
        self.seed = seed

    def drop(self) -> None:
        """No re-solve any more (accepted, refused for good, or another filter publishes)."""
        self.seed = None

    def end(self, reason: str) -> None:
        """Give the re-solves up, counted under `reason`."""
        if self.seed is not None:
            self.seed = None
            counts = self.report.ff_extension_rejections
            counts[reason] = counts.get(reason, 0) + 1

    def due_times(self, newest_ns: int) -> list[int] | None:
        """Ideal camera times of the newer frames of a due re-solve (spaced back from `newest_ns` to just
        after the window), or None: not due yet, or expired (counted, the seed dropped)."""
        seed = self.seed
        if seed is None:
            return None
        if newest_ns - seed.last_ns > self.extend_ns:
            self.seed = None
            self.report.ff_extension_expired += 1
            return None
        if newest_ns - self._tried_ns < 0.999 * self.spacing_ns:
            return None
        n = 0
        while newest_ns - n * self.spacing_ns > seed.last_ns + 0.5 * self.spacing_ns:
            n += 1
        return [int(newest_ns - round(k * self.spacing_ns)) for k in range(n - 1, -1, -1)]

    def note(self, stamps: list[int]) -> None:
        """Count a re-solve over `stamps`; the next waits one spacing after its newest frame."""
        self.report.ff_extensions += 1
        self._tried_ns = int(stamps[-1])
