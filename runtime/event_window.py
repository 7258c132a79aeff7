"""The first seconds of a merged camera-IMU event stream (`davio run|live|calibrate --seconds`)."""
from __future__ import annotations

from collections.abc import Iterable, Iterator

from runtime.events import Frame, ImuSample


def first_seconds(events: Iterable[ImuSample | Frame], seconds: float) -> Iterator[ImuSample | Frame]:
    """The events of the first `seconds` of data, counted from where both streams run (the later of the first
    image and the first IMU sample), so that a stray early stamp in one stream (a corrupt first row, 0 ns)
    does not use up the span before the data starts. While only one stream has begun, the span counts from
    its first event (a stream of one kind alone still ends)."""
    first: dict[bool, int] = {}
    t0: int | None = None
    for ev in events:
        t = int(ev.t_ns)
        if t0 is None:
            first.setdefault(isinstance(ev, Frame), t)
            if len(first) == 2:
                t0 = max(first.values())
        start = t0 if t0 is not None else min(first.values())
        if (t - start) * 1e-9 > seconds:
            return
        yield ev
