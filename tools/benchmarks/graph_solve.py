"""`davio bench graph-solve`: what one solve of the submap graph costs, by graph size.

A synthetic graph like the mapper builds: N submaps 1.5 m apart on a closed loop (cameras facing out), each
linked to the previous one by odometry (with drift noise), a shared-image scale link and an adjacent point
group of 80 correspondences, and every fourth node by a revisit point group (80) and scale link to the node
eight back. The free nodes are then perturbed (20 cm, 3 deg of yaw, 0.05 in lambda) and one solve is timed
(`SubmapGraph.solve`: 8 LM iterations, sparse Jacobian, LSMR trust-region step), beside the same problem
solved with scipy's exact (dense SVD) trust-region step for reference. Median of --repeats solves, BLAS on
one thread as in the runtime. Sizes: the 24 fused submaps, and the graph window (64 by default).
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from tools.cli_types import count

NAME = "graph-solve"
HELP = "submap-graph solve time by size (sparse LSMR step, and the exact dense step for reference)"
DESCRIPTION = __doc__


MAX_NODES = 2000
"""Largest --sizes node count (a dense graph of this size already takes gigabytes)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sizes", default="24,48,64,96", help="comma-separated node counts")
    p.add_argument("--repeats", type=count(1, 1000), default=5, help="solves timed per size (median)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="FILE.json", help="also write the JSON here")


def synthetic_graph(n: int, seed: int = 0):
    """(graph with perturbed free nodes, true T_MS (n,4,4), true lambdas (n,)) as the module docstring."""
    from runtime.geometry import make_pose, rot_z, se3_exp, se3_inverse
    from runtime.graph import GraphConfig, SubmapGraph

    rng = np.random.default_rng(seed)
    r = 1.5 * n / (2 * math.pi)
    R_bc = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])   # camera in a z-up body

    angles = 2 * math.pi * np.arange(n) / n
    Ts = np.array([make_pose(rot_z(a) @ R_bc, np.array([r * math.cos(a), r * math.sin(a), 1.0]))
                   for a in angles])
    lams = np.concatenate([[0.0], rng.normal(0.0, 0.05, n - 1)])

    def points(a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        pc = np.column_stack([rng.uniform(-2, 2, 80), rng.uniform(-1, 1, 80), rng.uniform(2, 6, 80)])
        X = pc @ Ts[a][:3, :3].T + Ts[a][:3, 3]
        pa = (X - Ts[a][:3, 3]) @ Ts[a][:3, :3] / math.exp(lams[a])
        pb = (X - Ts[b][:3, 3]) @ Ts[b][:3, :3] / math.exp(lams[b])
        noise = 0.02
        return pa + rng.normal(0, noise, pa.shape), pb + rng.normal(0, noise, pb.shape)

    g = SubmapGraph(GraphConfig(max_resident_nodes=max(n, 1)))
    for j in range(n):
        T = Ts[j].copy()
        lam = lams[j]
        if j:
            T[:3, :3] = rot_z(rng.normal(0, math.radians(3))) @ T[:3, :3]
            T[:3, 3] += rng.normal(0, 0.2, 3)
            lam += rng.normal(0, 0.05)
        g.add_node(j, T, lam)
    for b in range(1, n):
        a = b - 1
        xi = np.concatenate([rng.normal(0, 0.01, 3), rng.normal(0, 0.0025, 3)])
        g.add_odometry(a, b, se3_inverse(Ts[a]) @ Ts[b] @ se3_exp(xi))
        g.add_scale_link(a, b, lams[b] - lams[a] + rng.normal(0, 0.01), 0.03)
        g.add_points(a, b, *points(a, b), adjacent=True)
        if b >= 8 and b % 4 == 0:
            g.add_points(b - 8, b, *points(b - 8, b), adjacent=False)
            g.add_scale_link(b - 8, b, lams[b] - lams[b - 8], 0.03, kind="revisit")
    return g, Ts, lams


def _dense_solve_s(g) -> tuple[float, float]:
    """(seconds, final cost) of the same problem with scipy's exact (dense SVD) trust-region step."""
    from scipy.optimize import least_squares

    from runtime.graph.graph import _blas_threads, solver_x_scale

    t0 = time.perf_counter()
    prob = g.problem()
    x0 = np.zeros(prob.n_params)
    with _blas_threads(g.cfg.blas_threads):
        res = least_squares(prob.residual, x0, jac=lambda x: prob.jacobian(x).toarray(), method="trf",
                            tr_solver="exact", loss=prob.loss,
                            x_scale=solver_x_scale(prob),
                            max_nfev=g.cfg.max_iterations + 1)
    return time.perf_counter() - t0, prob.cost(res.x)


def measure(n: int, repeats: int) -> dict:
    import copy

    times, dense, cost, dcost = [], [], 0.0, 0.0
    g0, *_ = synthetic_graph(n)
    prob = g0.problem()
    for _ in range(repeats):
        g = copy.deepcopy(g0)
        rep = g.solve()
        times.append(rep.time_s)
        cost = rep.cost_after
        gd = copy.deepcopy(g0)
        s, dcost = _dense_solve_s(gd)
        dense.append(s)
    return {"nodes": n, "params": prob.n_params, "residuals": prob.n_residuals,
            "point_groups": len(g0.point_groups), "solve_s": float(np.median(times)),
            "dense_exact_s": float(np.median(dense)), "cost_after": cost, "dense_cost_after": dcost,
            "cost_before": rep.cost_before}


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from runtime.errors import ConfigError
    from runtime.json_out import strict_dumps

    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError as exc:
        raise ConfigError(f"--sizes takes comma-separated integers, got {args.sizes!r}") from exc
    if not sizes or min(sizes) < 2 or max(sizes) > MAX_NODES or args.repeats < 1:
        raise ConfigError(f"--sizes must be node counts from 2 to {MAX_NODES} (the dense solve is quadratic: "
                          f"20000 took 10 GB) and --repeats >= 1, got {args.sizes!r}")
    rows = [measure(n, args.repeats) for n in sizes]
    result = {"benchmark": NAME, "repeats": args.repeats, "rows": rows}
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=2))
    if args.json:
        print(strict_dumps(result))
        return 0
    print("one submap-graph solve (8 LM iterations), median of", args.repeats)
    print(f"  {'nodes':>5} {'params':>6} {'rows':>7} {'groups':>6} {'sparse LSMR (s)':>16} "
          f"{'dense exact (s)':>16} {'cost before -> after (sparse / dense)':>40}")
    for r in rows:
        print(f"  {r['nodes']:5d} {r['params']:6d} {r['residuals']:7d} {r['point_groups']:6d} "
              f"{r['solve_s']:16.3f} {r['dense_exact_s']:16.3f}   {r['cost_before']:10.1f} -> "
              f"{r['cost_after']:.2f} / {r['dense_cost_after']:.2f}")
    return 0
