"""PoseHistory: the published states come back bit for bit across chunk boundaries, and a failed append
records nothing. (What a pose costs, against the objects it replaces, is measured by `davio bench long-run`
and asserted in tests/tools/test_bench_long_run.py.)"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from runtime.pose_history import CHUNK_ROWS, PoseHistory
from runtime.startup import Published


def _state(rng: np.random.Generator, k: int) -> tuple[Published, np.ndarray, int, float]:
    R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    src = ("native:static", "feedforward", "native:dynamic")[k % 3]
    B = rng.normal(size=(6, 6))
    p = Published(1_000_000_000 + 50_000_000 * k, 1_000_000_000 + 50_000_000 * k - 7, R, rng.normal(size=3),
                  rng.normal(size=3), src, filter_id=k // 100, segment=k // 1000, covariance=B @ B.T)
    T_MI = np.eye(4)
    T_MI[:3, :3] = Rotation.random(random_state=k).as_matrix()
    T_MI[:3, 3] = rng.normal(size=3) * 100
    return p, T_MI, k // 7, float(rng.uniform())


def test_states_and_causal_poses_come_back_bit_for_bit_across_chunks() -> None:
    rng = np.random.default_rng(3)
    n = CHUNK_ROWS + 37
    given = [_state(rng, k) for k in range(n)]
    h = PoseHistory()
    for p, T, v, f in given:
        h.append(p, T, v, f)
    assert len(h) == len(h.published) == len(h.causal) == n
    for k in (0, 1, CHUNK_ROWS - 1, CHUNK_ROWS, n - 1):
        p, T, v, f = given[k]
        got = h.published[k]
        assert (got.t_ns, got.t_cam_ns, got.source, got.filter_id, got.segment) == \
            (p.t_ns, p.t_cam_ns, p.source, p.filter_id, p.segment)
        assert np.array_equal(got.R_OI, p.R_OI) and np.array_equal(got.p_OI, p.p_OI)
        assert np.array_equal(got.v_OI, p.v_OI) and np.array_equal(got.T_OI, p.T_OI)
        assert got.covariance is None                  # not kept: the live consumer had it
        T_got, v_got, f_got = h.causal[k]
        assert np.array_equal(T_got, T) and v_got == v and f_got == f
    # negative indices, slices across the chunk boundary, iteration and the row block agree
    assert h.published[-1].t_ns == given[-1][0].t_ns
    sl = h.published[CHUNK_ROWS - 2:CHUNK_ROWS + 3]
    assert [s.t_ns for s in sl] == [given[k][0].t_ns for k in range(CHUNK_ROWS - 2, CHUNK_ROWS + 3)]
    assert [c[1] for c in h.causal[n - 5:]] == [given[k][2] for k in range(n - 5, n)]
    assert [s.t_ns for s in h.published] == [g[0].t_ns for g in given]
    rows = h.rows(CHUNK_ROWS - 3, CHUNK_ROWS + 2)
    assert rows["t_ns"].tolist() == [given[k][0].t_ns for k in range(CHUNK_ROWS - 3, CHUNK_ROWS + 2)]
    assert len(h.rows(5, 5)) == 0 and len(h.rows()) == n
    with pytest.raises(IndexError):
        h.published[n]
    with pytest.raises(IndexError):
        h.causal[-n - 1]


def test_an_append_that_fails_records_nothing_and_leaves_later_rows_in_place() -> None:
    rng = np.random.default_rng(4)
    h = PoseHistory()
    good = [_state(rng, k) for k in range(CHUNK_ROWS + 2)]
    for p, T, v, f in good[:CHUNK_ROWS]:
        h.append(p, T, v, f)
    p, T, v, f = good[CHUNK_ROWS]
    for bad in (replace(p, t_ns=2**63), replace(p, p_OI=np.zeros(2))):   # at a chunk's first row
        with pytest.raises((OverflowError, ValueError)):
            h.append(bad, T, v, f)
        assert len(h) == CHUNK_ROWS
    for p, T, v, f in good[CHUNK_ROWS:]:
        h.append(p, T, v, f)
    assert [s.t_ns for s in h.published[CHUNK_ROWS - 1:]] == [g[0].t_ns for g in good[CHUNK_ROWS - 1:]]
    assert np.array_equal(h.published[CHUNK_ROWS].R_OI, good[CHUNK_ROWS][0].R_OI)
