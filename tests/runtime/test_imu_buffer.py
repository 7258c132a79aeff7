"""The IMU sample buffer against a plain list model, through growth, compaction and drops."""
from __future__ import annotations

import numpy as np

from runtime.imu.buffer import ImuBuffer


def test_buffer_matches_a_list_model_through_growth_compaction_and_drops() -> None:
    rng = np.random.default_rng(3)
    buf = ImuBuffer(capacity=8)
    model: list[tuple[int, np.ndarray, np.ndarray]] = []
    t = 0
    for step in range(2000):
        t += int(rng.integers(1, 5_000_000))
        w, a = rng.normal(size=3), rng.normal(size=3)
        buf.append(t, w, a)
        model.append((t, w, a))
        if step % 37 == 0:
            n = int(rng.integers(0, len(model) + 1))
            buf.drop_first(n)
            model = model[n:]
        if step % 101 == 0 and model:
            cut = model[len(model) // 2][0]
            buf.drop_before(cut)
            model = [m for m in model if m[0] >= cut]
        assert len(buf) == len(model)
        if model:
            assert buf.first_ns == model[0][0] and buf.last_ns == model[-1][0]
            assert np.array_equal(buf.t_ns, [m[0] for m in model])
            assert np.array_equal(buf.gyro, np.array([m[1] for m in model]))
            assert np.array_equal(buf.accel, np.array([m[2] for m in model]))
        else:
            assert buf.first_ns is None and buf.last_ns is None
    # bounded: a window of live samples never grows the arrays past twice its peak
    assert buf._t.shape[0] <= 2 * 2048


def test_empty_buffer_and_clear() -> None:
    buf = ImuBuffer()
    assert len(buf) == 0 and buf.first_ns is None and buf.t_ns.shape == (0,)
    buf.append(5, np.ones(3), np.zeros(3))
    buf.drop_before(6)
    assert len(buf) == 0
    buf.append(7, np.ones(3), np.zeros(3))
    buf.clear()
    assert len(buf) == 0 and buf.last_ns is None
