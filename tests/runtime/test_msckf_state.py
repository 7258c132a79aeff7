"""State.apply_correction: the boxplus of every block against scipy's rotation vectors."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from runtime.msckf.state import Clone, Landmark, State


def test_apply_correction_moves_every_block_by_its_slice() -> None:
    rng = np.random.default_rng(2)
    st = State(np.eye(3), np.zeros(3), 0.0, calib_dt=True, calib_ext=True)
    st.R = Rotation.random(random_state=1).as_matrix()
    n = st.size
    clones, landmarks = {}, {}
    for k in range(4):
        R = Rotation.random(random_state=10 + k).as_matrix()
        p = rng.normal(size=3)
        clones[1000 + k] = Clone(1000 + k, R, p, R.copy(), p.copy(), n)
        n += 6
    for fid in range(3):
        p = rng.normal(size=3)
        landmarks[fid] = Landmark(fid, p, p.copy(), n)
        n += 3
    st.P = np.eye(n)
    st.clones, st.slam = clones, landmarks
    before = {t: (c.R.copy(), c.p.copy()) for t, c in clones.items()}
    lm_before = {f: lm.p.copy() for f, lm in landmarks.items()}
    R_IC0, p_IC0 = st.R_IC.copy(), st.p_IC.copy()
    R0 = st.R.copy()
    dx = rng.normal(scale=0.05, size=n)
    st.apply_correction(dx)
    np.testing.assert_allclose(st.R, R0 @ Rotation.from_rotvec(dx[0:3]).as_matrix(), atol=1e-13)
    np.testing.assert_allclose(st.v, dx[6:9], atol=0)
    assert st.t_d == dx[st.idx_dt]
    i = st.idx_ext
    np.testing.assert_allclose(st.R_IC, R_IC0 @ Rotation.from_rotvec(dx[i:i + 3]).as_matrix(), atol=1e-13)
    np.testing.assert_allclose(st.p_IC, p_IC0 + dx[i + 3:i + 6], atol=0)
    for t, c in clones.items():
        R, p = before[t]
        np.testing.assert_allclose(c.R, R @ Rotation.from_rotvec(dx[c.idx:c.idx + 3]).as_matrix(), atol=1e-13)
        np.testing.assert_allclose(c.p, p + dx[c.idx + 3:c.idx + 6], atol=1e-15)
        np.testing.assert_array_equal(c.R_fej, R)          # first estimates untouched
    for f, lm in landmarks.items():
        np.testing.assert_array_equal(lm.p, lm_before[f] + dx[lm.idx:lm.idx + 3])
        np.testing.assert_array_equal(lm.p_fej, lm_before[f])
    # each clone keeps its own values: writing into one leaves the others
    first, *others = clones.values()
    kept = [o.R.copy() for o in others]
    first.R[...] = 0.0
    for o, R in zip(others, kept, strict=True):
        np.testing.assert_array_equal(o.R, R)
