"""GraphBackend (runtime/graph/backend.py): the graph window, evicted nodes kept for revisits, a revisit
closing a loop on an evicted node through an anchor, one solve per commit, and candidate ranking."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from graph_synth import corresponding_points, loop_poses

from runtime.geometry import make_pose, se3_inverse, so3_exp
from runtime.graph import GraphConfig, GraphError
from runtime.graph.backend import GraphBackend
from runtime.graph.config import RevisitConfig
from runtime.graph.revisits import RevisitView

N = 16
K = np.array([[400.0, 0.0, 319.5], [0.0, 400.0, 239.5], [0.0, 0.0, 1.0]])
W, H = 640, 480


@dataclass
class Link:
    kappa: float = 0.0
    sigma: float = 0.03
    method: str = "shared"


def drifted_backend(window: int = 8, drift_deg: float = 0.5) -> tuple[GraphBackend, np.ndarray]:
    """A loop of N submaps whose odometry drifts drift_deg of yaw per edge (about the camera's y axis,
    which is the gravity axis here), fed with scale links only (no point groups); the graph keeps
    `window` nodes. Returns (backend, true T_MS)."""
    Ts = loop_poses(N)
    bias = make_pose(so3_exp(np.array([0.0, np.radians(drift_deg), 0.0])), np.zeros(3))
    be = GraphBackend(GraphConfig(max_resident_nodes=window), RevisitConfig())
    T_OS = Ts[0]
    for j in range(N):
        if j:
            T_OS = T_OS @ se3_inverse(Ts[j - 1]) @ Ts[j] @ bias
        be.add_submap(j, T_OS, segment=0, prev=j - 1 if j else None, link=Link() if j else None,
                      t_ns=int(j * 1.5e9))
        be.finish_commit()
    return be, Ts


def test_the_window_keeps_the_newest_nodes_and_remembers_the_evicted_states():
    be, _ = drifted_backend(window=8)
    assert be.graph.node_ids == list(range(8, N)) and be.stats.evicted == 8
    assert be.graph.gauge == 8 and be.graph.node_state(8).fixed
    T0, lam0 = be.state(0)                         # evicted: the state it left with
    np.testing.assert_array_equal(T0, be._evicted[0][0])
    assert lam0 == 0.0
    with pytest.raises(GraphError):
        be.graph.node_state(0)


def test_a_revisit_to_an_evicted_node_closes_the_loop_through_an_anchor():
    be, Ts = drifted_backend(window=8)
    last = N - 1
    # the evicted node 0 was the gauge: its stored state is the truth; node 15 drifted
    before = float(np.linalg.norm(be.state(last)[0][:3, 3] - Ts[last][:3, 3]))
    solves = be.stats.solves
    pa, pb = corresponding_points(Ts[0], 0.0, Ts[last], 0.0, 80, np.random.default_rng(3))
    be.add_revisit(0, last, 0.0, (pa, pb))
    assert be.graph.anchor_ids == [0] and be.stats.anchors_added == 1 and be.stats.solves == solves
    rep = be.finish_commit()                        # one solve for everything the commit added
    assert rep is not None and be.stats.solves == solves + 1 and 0 not in rep.changes
    after = float(np.linalg.norm(be.state(last)[0][:3, 3] - Ts[last][:3, 3]))
    assert before > 0.1 and after < 0.85 * before
    np.testing.assert_array_equal(be.state(0)[0], Ts[0])
    assert be.finish_commit() is None               # nothing new: no solve
    with pytest.raises(GraphError, match="neither"):
        be.add_revisit(-5, last, 0.0, None)


def test_candidates_need_overlap_time_gap_and_distance():
    be, Ts = drifted_backend(window=8)
    u, v = np.meshgrid(np.linspace(0, W - 1, 12), np.linspace(0, H - 1, 12))
    kp = np.column_stack([u.ravel(), v.ravel()])
    for j in range(N):
        be.add_view(j, None, RevisitView(K, kp, np.full(len(kp), 4.0), (W, H)))
    last = N - 1
    # a loop of radius 3 m: node 15 sees part of what 14 (1.5 s apart), 0 and 1 see; the far side faces away
    cands = be.candidates(last)
    assert cands and all(be._t_ns[last] - be._t_ns[a] >= 5e9 for a in cands)
    assert 0 in cands and not set(cands) & {6, 7, 8, 9}
    assert be.stats.candidates_low_overlap > 0
    assert len(cands) <= be.revisit_cfg.max_candidates
