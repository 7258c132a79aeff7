"""`davio bench graph-solve`: its synthetic graph is solved back to the truth it was built from, the
sparse LSMR step reaches the exact dense step's cost, and the command prints and writes its figures."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tools.benchmarks.graph_solve import measure, synthetic_graph
from tools.cli import main


def test_the_synthetic_graph_solves_back_to_its_truth():
    g, Ts, lams = synthetic_graph(12)
    before = max(np.linalg.norm(g.node_state(j).T_MS[:3, 3] - Ts[j][:3, 3]) for j in range(12))
    g.solve(max_iterations=30)
    after = max(np.linalg.norm(g.node_state(j).T_MS[:3, 3] - Ts[j][:3, 3]) for j in range(12))
    lam_err = max(abs(g.node_state(j).lam - lams[j]) for j in range(12))
    assert before > 0.2 and after < 0.05 and lam_err < 0.03


def test_sparse_and_dense_steps_reach_the_same_cost():
    r = measure(16, 1)
    # 15 free nodes of 5 parameters and the gauge's lambda (GraphConfig.gauge_lambda_free, the default)
    assert r["nodes"] == 16 and r["params"] == 15 * 5 + 1 and r["point_groups"] == 15 + 2
    assert r["cost_after"] < 0.01 * r["cost_before"]
    assert r["cost_after"] == pytest.approx(r["dense_cost_after"], rel=0.05)


def test_command_prints_and_writes(tmp_path, capsys):
    out = tmp_path / "g.json"
    assert main(["bench", "graph-solve", "--sizes", "8,12", "--repeats", "1", "--out", str(out)]) == 0
    assert "sparse LSMR" in capsys.readouterr().out
    rows = json.loads(out.read_text())["rows"]
    assert [r["nodes"] for r in rows] == [8, 12]
    assert main(["bench", "graph-solve", "--sizes", "1"]) == 1
    assert "--sizes" in capsys.readouterr().err
