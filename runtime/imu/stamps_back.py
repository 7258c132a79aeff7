"""IMU stamps that went back: how much real time a clock that jumped back took to pass its newest stamp."""
from __future__ import annotations


class StampsBehind:
    """The samples stamped at or behind the newest one, between two samples past it.

    A clock that jumped back B s stamps B s of samples behind the newest before it passes it; their stamps
    step on at the sensor's rate, and the sum of those steps is real time with no usable sample, however
    close the stamps on either side of it are. Steps longer than `max_step_ns` (between a stray stamp and a
    repeat of the newest, say) are not a clock running on and count nothing; a single stray or repeated
    stamp spans nothing.
    """

    def __init__(self, max_step_ns: int) -> None:
        self.max_step_ns = int(max_step_ns)
        self._prev: int | None = None
        self._span = 0

    def behind(self, t_ns: int) -> None:
        """A sample stamped at or behind the newest (ns)."""
        t = int(t_ns)
        if self._prev is not None and 0 < t - self._prev <= self.max_step_ns:
            self._span += t - self._prev
        self._prev = t

    def passed(self) -> int:
        """A sample past the newest came: the span (ns) the stamps behind it ran through; clears."""
        span, self._prev, self._span = self._span, None, 0
        return span
