"""IMU stamps that went back: how much real time a clock that jumped back took to pass its newest stamp."""
from __future__ import annotations


class StampsBehind:
    """The samples stamped at or behind the newest one, between two samples past it.

    A clock that jumped back B s stamps B s of samples behind the newest before it passes it: the span of
    those stamps (their clock runs on as usual) is real time with no usable sample, however close the stamps
    on either side of it are. A single stray or repeated stamp spans nothing.
    """

    def __init__(self) -> None:
        self._lo: int | None = None
        self._hi: int | None = None

    def behind(self, t_ns: int) -> None:
        """A sample stamped at or behind the newest (ns)."""
        t = int(t_ns)
        self._lo = t if self._lo is None else min(self._lo, t)
        self._hi = t if self._hi is None else max(self._hi, t)

    def passed(self) -> int:
        """A sample past the newest came: the span (ns) of the stamps behind since the last one; clears."""
        span = 0 if self._lo is None or self._hi is None else self._hi - self._lo
        self._lo = self._hi = None
        return span
