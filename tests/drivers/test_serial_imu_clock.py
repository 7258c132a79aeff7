"""Device-clock fit against a simulated serial link (notes/drivers.md §2): skew, jitter, spikes, jumps."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.serial_imu.clock import DeviceClock, Unwrapper

RATE_HZ = 400
PERIOD_NS = 2_500_000
SKEW = 80e-6


def simulate(seconds: float, seed: int, fifo: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Device stamps, true host sampling times and host arrival stamps.

    The device samples every 2.5 ms of its clock, which runs 80 ppm slow against the host; each
    sample arrives 1 ms + Exp(0.5 ms) later, 1 % of them 5-30 ms later still. With `fifo`, a delayed
    sample holds back the ones behind it and the host reads every ~2 ms, stamping a whole read at once.
    """
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE_HZ)
    dev = 7_000_000_000 + np.arange(n, dtype=np.int64) * PERIOD_NS
    true = 50_000_000_000 + np.round((dev - dev[0]) * (1 + SKEW)).astype(np.int64)
    lat = 1e6 + rng.exponential(0.5e6, n)
    spikes = rng.random(n) < 0.01
    lat[spikes] += rng.uniform(5e6, 30e6, spikes.sum())
    arrival = true + lat.astype(np.int64)
    if fifo:
        arrival = np.maximum.accumulate(arrival)
        reads = np.cumsum(rng.uniform(0.5e6, 3.5e6, 2 * n)).astype(np.int64) + true[0]
        assert reads[-1] > arrival[-1]
        arrival = reads[np.searchsorted(reads, arrival)]
    return dev, true, arrival


def run(clock: DeviceClock, dev: np.ndarray, arrival: np.ndarray) -> np.ndarray:
    """Stamps of the samples, -1 where the clock dropped one."""
    out = [clock.update(int(d), int(a)) for d, a in zip(dev, arrival, strict=True)]
    return np.array([-1 if t is None else t for t in out], dtype=np.int64)


@pytest.mark.parametrize("fifo", [False, True])
def test_fit_removes_jitter_and_spikes(fifo: bool) -> None:
    dev, true, arrival = simulate(60.0, seed=1 + fifo, fifo=fifo)
    clock = DeviceClock()
    stamps = run(clock, dev, arrival)
    assert np.all(np.diff(stamps) > 0)
    warm = slice(2 * RATE_HZ, None)                     # after 2 s
    err_ms = (stamps - true)[warm] / 1e6
    raw_ms = (arrival - true)[warm] / 1e6
    bias = float(np.median(err_ms))
    assert 0.95 < bias < 1.1                            # the constant minimum latency (1 ms) stays
    # notes model: ~0.002 ms; with the FIFO and polled reads the envelope is ~0.1 ms coarser per bin
    assert err_ms.std() < (0.05 if fifo else 0.01) and np.abs(err_ms - bias).max() < 0.15
    assert raw_ms.std() > 1.5                           # arrival stamps: ~2 ms (notes: 1.96 ms)
    assert abs(clock.drift_ppm - 80.0) < 3.0
    rep = clock.report()
    assert rep["clock_jumps"] == 0 and rep["clock_fitted"] and 0 < rep["fit_residual_ns"] < 150_000
    assert abs(rep["offset_ns"] - (true[-1] - dev[-1]) - bias * 1e6) < 100_000
    # the first 2 s are usable too: the running minimum (within 0.1 s), then the first line fits
    assert np.abs((stamps - true)[RATE_HZ // 10:2 * RATE_HZ] / 1e6 - bias).max() < 0.5


def test_device_reset_backwards_restarts_the_fit() -> None:
    dev, true, arrival = simulate(30.0, seed=3)
    k = 15 * RATE_HZ
    dev = dev.copy()
    dev[k:] = dev[k:] - dev[k] + 123 * PERIOD_NS       # device rebooted: its time starts again near 0
    clock = DeviceClock()
    stamps = run(clock, dev, arrival)
    assert clock.jumps == 1 and list(np.flatnonzero(stamps < 0)) == [k]      # the reset costs one sample
    assert clock.backward_dropped == 1 and np.all(np.diff(np.delete(stamps, k)) > 0)
    after = (stamps - true)[k + 2 * RATE_HZ:] / 1e6
    assert after.std() < 0.03 and abs(np.median(after) - 1.0) < 0.1


def test_one_sample_stamped_back_is_dropped_not_made_the_origin() -> None:
    """A firmware glitch (one line carrying an older time) restarted the fit on it: the next 0.5 s of
    stamps ran up to 255 ms early, then a 372 ms gap."""
    dev, true, arrival = simulate(12.0, seed=6)
    k = 6 * RATE_HZ
    dev = dev.copy()
    dev[k] = dev[k - 150]
    clock = DeviceClock()
    stamps = run(clock, dev, arrival)
    assert list(np.flatnonzero(stamps < 0)) == [k] and clock.jumps == 0 and clock.backward_dropped == 1
    err_ms = (np.delete(stamps, k) - np.delete(true, k))[2 * RATE_HZ:] / 1e6
    assert np.abs(err_ms - np.median(err_ms)).max() < 0.5 and clock.report()["stamps_clamped"] == 0


def test_device_clock_step_forward_and_lost_time_are_jumps() -> None:
    dev, true, arrival = simulate(30.0, seed=4)
    k = 12 * RATE_HZ
    fwd = dev.copy()
    fwd[k:] += 1_000_000_000                            # device time steps 1 s ahead
    clock = DeviceClock()
    stamps = run(clock, fwd, arrival)
    assert clock.jumps == 1 and np.all(np.diff(stamps) > 0)
    assert ((stamps - true)[k + 2 * RATE_HZ:] / 1e6).std() < 0.03
    # device clock loses 2 s (it paused while the host went on): samples look 2 s late, persistently
    late = arrival.copy()
    true2 = true.copy()
    late[k:] += 2_000_000_000
    true2[k:] += 2_000_000_000
    clock = DeviceClock()
    stamps = run(clock, dev, late)
    assert clock.jumps == 1 and np.all(np.diff(stamps) > 0)
    assert ((stamps - true2)[k + 3 * RATE_HZ:] / 1e6).std() < 0.03


def test_short_host_stall_is_not_a_jump() -> None:
    dev, true, arrival = simulate(20.0, seed=5)
    k = 10 * RATE_HZ
    arrival = arrival.copy()
    arrival[k:k + 80] = arrival[k + 80]                 # the reader was blocked 200 ms, then read a burst
    clock = DeviceClock()
    stamps = run(clock, dev, arrival)
    assert clock.jumps == 0
    err = (stamps - true)[2 * RATE_HZ:] / 1e6
    assert err.std() < 0.03


def test_unwrapper() -> None:
    u = Unwrapper(1 << 16)
    assert [u.update(v) for v in (65534, 65535, 0, 1, 3)] == [65534, 65535, 65536, 65537, 65539]
    assert u.wraps == 1
    assert u.update(0) == 65536                          # a step back stays a step back
    u.reset()
    assert u.update(10) == 10
    with pytest.raises(ValueError):
        Unwrapper(1)
    with pytest.raises(ValueError):
        DeviceClock(bin_s=0.5, window_s=0.5)
