"""Device clock -> host clock: counter unwrapping and an online lower-envelope line fit.

A serial IMU stamps each sample with its own clock (a tick counter that wraps); the host only
knows when the bytes *arrived* (`time.monotonic_ns()` right after `read()`), which is the true
sampling time plus a latency of >= ~1 ms plus USB/OS jitter and occasional spikes of tens of ms.
Arrival minus device time is therefore bounded below by the clock offset plus the minimum
latency; its lower envelope is a line (Olson, "A passive solution to the sensor synchronization
problem", IROS 2010):

    host = a + (1 + drift) * device

`DeviceClock` keeps the minimum of (host - device) per `bin_s` of device time, fits that line by
least squares over the last `window_s` (one outlier-rejection pass for bins that were entirely
delayed, e.g. by a stalled reader), and maps each sample's device time onto the host clock. The
constant minimum latency stays in the stamps (the camera-IMU time-offset calibration absorbs
it). Measured on the simulation of notes/drivers.md §2 (80 ppm, 1 ms + exponential jitter, 1 %
spikes of 5-30 ms): stamp error std ~0.03 ms against ~2 ms for arrival stamps.

Clock jumps (device reset, counter glitch): the device time going backwards on two samples in a row,
a sample arriving impossibly early for the fit (the device clock stepped forward) or a sample
persistently late by more than `behind_tolerance_s` (the device clock stepped back) are counted and
restart the fit. A single sample behind the previous one, followed by one that continues the timeline,
is a glitch: that sample is dropped (`update` returns None; `backward_dropped`), not made the new origin
(which skewed the next half second of stamps by up to 0.25 s). A real reset costs its first sample, also
counted there. Output stamps are strictly increasing int64 ns.
"""
from __future__ import annotations

import math
from collections import deque


class Unwrapper:
    """Unwraps a modular tick counter (e.g. a u32 of 0.1 ms ticks) into an unbounded int.

    A step of less than half the modulus is taken as forward or backward motion, whichever is
    shorter; steps backward (device reset) are passed on as they are, for the clock to detect.
    """

    def __init__(self, modulus: int) -> None:
        if modulus <= 1:
            raise ValueError("modulus must be > 1")
        self.modulus = int(modulus)
        self.wraps = 0
        """forward wrap-arounds seen"""
        self._last_raw: int | None = None
        self._value = 0

    def update(self, raw: int) -> int:
        """The unwrapped value of the next raw reading."""
        raw = int(raw)
        if self._last_raw is None:
            self._value = raw
        else:
            delta = (raw - self._last_raw) % self.modulus
            if delta <= self.modulus // 2:
                self._value += delta
                if raw < self._last_raw:
                    self.wraps += 1
            else:
                self._value -= self.modulus - delta
        self._last_raw = raw
        return self._value

    def reset(self) -> None:
        """Forget the history: the next reading starts a new unwrapped sequence."""
        self._last_raw = None


class DeviceClock:
    """Online map from unwrapped device time to host monotonic time (int64 ns).

    Args:
        bin_s: device-time length of the bins whose minimum of (host - device) is kept.
        window_s: the line is fitted over the bins of the last `window_s`.
        ahead_tolerance_s: a sample that arrives this much *before* the fitted line says it could
            have (the device clock stepped forward) is a jump.
        behind_tolerance_s, behind_persist_s: samples later than the line by more than
            `behind_tolerance_s` for longer than `behind_persist_s` of device time (the device clock
            stepped back, or lost time) are a jump. Shorter delays are host-side jitter.
        outlier_floor_s: bins above the first fit by more than max(this, 5 robust sigmas) are
            dropped from the second fit.
    """

    def __init__(self, bin_s: float = 0.5, window_s: float = 30.0, ahead_tolerance_s: float = 0.003,
                 behind_tolerance_s: float = 0.25, behind_persist_s: float = 0.5,
                 outlier_floor_s: float = 50e-6) -> None:
        if bin_s <= 0 or window_s < 2 * bin_s:
            raise ValueError("need bin_s > 0 and window_s >= 2 * bin_s")
        self.bin_ns = int(round(bin_s * 1e9))
        self.window_bins = int(math.ceil(window_s / bin_s))
        self.ahead_ns = float(ahead_tolerance_s * 1e9)
        self.behind_ns = float(behind_tolerance_s * 1e9)
        self.behind_persist_ns = int(behind_persist_s * 1e9)
        self.outlier_floor_ns = float(outlier_floor_s * 1e9)
        self.jumps = 0
        """restarts of the fit caused by clock jumps"""
        self.clamped = 0
        """output stamps raised to keep them strictly increasing"""
        self.backward_dropped = 0
        """samples dropped for a device time behind the previous sample's (a glitch, or a reset's first)"""
        self._suspect = False
        self.samples = 0
        self._last_out: int | None = None
        self._restart()

    # --- state -------------------------------------------------------------------------------
    def _restart(self) -> None:
        self._x0: int | None = None      # device ns origin of this segment
        self._y0 = 0                     # (host - device) origin of this segment, ns
        self._bins: deque[list] = deque()  # [bin index, x_rel, y_rel] minima; last one is open
        self._a = 0.0                    # fitted y_rel at x_rel = 0
        self._d = 0.0                    # drift (host ns per device ns - 1)
        self._fitted = False             # line fitted over >= 2 closed bins
        self._residual_ns = 0.0
        self._last_dev: int | None = None
        self._behind_since: int | None = None

    def _start(self, t_dev_ns: int, t_host_ns: int) -> None:
        self._x0 = t_dev_ns
        self._y0 = t_host_ns - t_dev_ns
        self._bins.append([0, 0.0, 0.0])
        self._a = 0.0

    # --- fit ---------------------------------------------------------------------------------
    @staticmethod
    def _lsq(points: list[tuple[float, float]]) -> tuple[float, float]:
        n = len(points)
        mx = sum(p[0] for p in points) / n
        my = sum(p[1] for p in points) / n
        sxx = sum((p[0] - mx) ** 2 for p in points)
        sxy = sum((p[0] - mx) * (p[1] - my) for p in points)
        d = sxy / sxx if sxx > 0 else 0.0
        return my - d * mx, d

    def _refit(self) -> None:
        closed = [(b[1], b[2]) for b in list(self._bins)[:-1]]
        if len(closed) < 2:
            self._a = min(b[2] for b in self._bins)
            self._d = 0.0
            self._fitted = False
            return
        a, d = self._lsq(closed)
        res = [y - (a + d * x) for x, y in closed]
        mad = sorted(abs(r) for r in res)[len(res) // 2] * 1.4826
        limit = max(5.0 * mad, self.outlier_floor_ns)
        inliers = [p for p, r in zip(closed, res, strict=True) if r <= limit]
        if 2 <= len(inliers) < len(closed):
            a, d = self._lsq(inliers)
        else:
            inliers = closed
        self._a, self._d, self._fitted = a, d, True
        self._residual_ns = math.sqrt(sum((y - (a + d * x)) ** 2 for x, y in inliers) / len(inliers))

    # --- public ------------------------------------------------------------------------------
    def update(self, t_dev_ns: int, t_host_ns: int) -> int | None:
        """Feed one sample (device time, host arrival time); returns its host-clock stamp, int ns, or None
        for a sample dropped as behind the previous one (module docstring)."""
        t_dev_ns, t_host_ns = int(t_dev_ns), int(t_host_ns)
        self.samples += 1
        if self._x0 is None:
            self._start(t_dev_ns, t_host_ns)
        elif self._last_dev is not None and t_dev_ns < self._last_dev:
            if not self._suspect:       # a glitch or a reset: the next sample tells
                self._suspect = True
                self.backward_dropped += 1
                return None
            self._suspect = False
            self._jump(t_dev_ns, t_host_ns)
        else:
            self._suspect = False
            y = float(t_host_ns - t_dev_ns - self._y0)
            x = float(t_dev_ns - self._x0)
            r = y - (self._a + self._d * x)
            has_closed = len(self._bins) >= 2
            if has_closed and r < -self.ahead_ns:
                self._jump(t_dev_ns, t_host_ns)
            elif has_closed and r > self.behind_ns and self._behind(t_dev_ns):
                self._jump(t_dev_ns, t_host_ns)
            else:
                if r <= self.behind_ns:
                    self._behind_since = None
                self._add(x, y, t_dev_ns)
        self._last_dev = t_dev_ns
        x = float(t_dev_ns - self._x0)
        out = t_dev_ns + self._y0 + int(round(self._a + self._d * x))
        if self._last_out is not None and out <= self._last_out:
            out = self._last_out + 1
            self.clamped += 1
        self._last_out = out
        return out

    def _behind(self, t_dev_ns: int) -> bool:
        if self._behind_since is None:
            self._behind_since = t_dev_ns
        return t_dev_ns - self._behind_since > self.behind_persist_ns

    def _jump(self, t_dev_ns: int, t_host_ns: int) -> None:
        self.jumps += 1
        self._restart()
        self._start(t_dev_ns, t_host_ns)

    def _add(self, x: float, y: float, t_dev_ns: int) -> None:
        b = (t_dev_ns - self._x0) // self.bin_ns
        last = self._bins[-1]
        if b == last[0]:
            if y < last[2]:
                last[1], last[2] = x, y
                if not self._fitted and len(self._bins) < 3:
                    self._a = min(self._a, y)
            return
        self._bins.append([b, x, y])
        while self._bins and self._bins[0][0] <= b - self.window_bins:
            self._bins.popleft()
        self._refit()

    @property
    def drift_ppm(self) -> float:
        """Fitted rate difference of host vs device clock, parts per million."""
        return self._d * 1e6

    @property
    def offset_ns(self) -> int:
        """host - device at the latest sample (includes the minimum latency), ns."""
        if self._x0 is None or self._last_dev is None:
            return 0
        return self._y0 + int(round(self._a + self._d * (self._last_dev - self._x0)))

    @property
    def residual_ns(self) -> float:
        """RMS of the bin minima about the fitted line (inliers), ns."""
        return self._residual_ns

    def report(self) -> dict:
        """JSON-ready state of the fit."""
        return {"clock_jumps": self.jumps, "drift_ppm": round(self.drift_ppm, 3),
                "offset_ns": self.offset_ns, "fit_residual_ns": round(self.residual_ns, 1),
                "clock_bins": len(self._bins), "clock_fitted": self._fitted,
                "stamps_clamped": self.clamped, "backward_dropped": self.backward_dropped}
