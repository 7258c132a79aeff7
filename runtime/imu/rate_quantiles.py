"""Quantiles of a whole run's angular rate in constant memory: a log-binned count of |gyro| (rad/s).

A gyroscope that logs deg/s reads 57.3 times too high. EuRoC's flights have median rates of 0.2-0.5 rad/s
and 90th percentiles of 0.6-1.0; in deg/s those read 13-29 and 34-57. The 90th percentile is judged, not
the median: a robot that stands still for most of a run has a median of its gyroscope's bias. A run whose
90th percentile exceeds GYRO_UNITS_P90_RAD_S (a racing drone's stays below it) is said on the console
(`davio run`) as a likely unit error.
"""
from __future__ import annotations

import math

import numpy as np

GYRO_UNITS_P90_RAD_S = 10.0
"""A run's 90th percentile of |gyro| above this (rad/s) is most likely a gyroscope in deg/s."""
_DECADES = (-3, 3)
_PER_DECADE = 20
"""Bins: 20 a decade from 1e-3 to 1e3 rad/s (12 % wide); rates outside fall in the end bins."""


class RateQuantiles:
    """Counts |gyro| in log bins; `quantile(q)` is the run's rate at q to within half a bin (6 %)."""

    def __init__(self) -> None:
        self.counts = np.zeros((_DECADES[1] - _DECADES[0]) * _PER_DECADE, np.int64)

    def add(self, gx: float, gy: float, gz: float) -> None:
        """One sample (rad/s); a non-finite one is not counted."""
        r = math.sqrt(gx * gx + gy * gy + gz * gz)
        if not math.isfinite(r):
            return
        k = int((math.log10(max(r, 1e-12)) - _DECADES[0]) * _PER_DECADE)
        self.counts[min(max(k, 0), self.counts.size - 1)] += 1

    @property
    def n(self) -> int:
        return int(self.counts.sum())

    def quantile(self, q: float) -> float | None:
        """The rate (rad/s, the centre of its bin in log scale) below which a fraction q of the samples lie;
        None before any sample."""
        n = self.n
        if not n:
            return None
        k = int(np.searchsorted(np.cumsum(self.counts), max(1, math.ceil(q * n))))
        return 10.0 ** (_DECADES[0] + (k + 0.5) / _PER_DECADE)
