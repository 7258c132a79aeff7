"""The stacked least-squares problem of one graph solve (paper eqs. graphres and objective).

Parameters: every free node i owns 5 columns x_i = (dt (3, m, map frame), dyaw (1, rad), dlam (1)),
offsets from its state when the solve started:

    R_i = Rz(dyaw) R_i0,   t_i = t_i0 + dt,   lambda_i = lambda_i0 + dlam,

with Rz a rotation about the map z axis (gravity). Left-multiplying by Rz keeps the third row of R_i,
i.e. R_i^T e_z (gravity seen from S_i: the filter's roll and pitch), exactly. Fixed nodes (the gauge)
own no columns.

Rows, in this order: odometry blocks (6 each), point blocks (3 each), scale priors (1 per free node),
scale links (1 each). Every block is whitened and, for point groups, multiplied by sqrt(1/N_ab); the
Huber loss on each block norm is applied by `robust.BlockHuber` (`self.loss`), so that
`self.loss.cost(f)` is the objective E exactly. The ray-aligned point whitening is frozen at the start
state (paper: frozen within a solve); the robust weights follow every accepted step.

The Jacobian is sparse (scipy CSR): each block touches the five columns of at most two nodes, so a solve
costs about linear in the factors and a wide graph window stays affordable.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

from runtime.geometry import make_pose, rot_z, se3_inverse, se3_log, skew
from runtime.graph.config import GraphConfig
from runtime.graph.factors import OdometryFactor, PointGroup, ScaleFactor
from runtime.graph.robust import BlockHuber
from runtime.graph.whitening import odometry_weights, point_whitening

NODE_PARAMS = 5
_EZ = np.array([0.0, 0.0, 1.0])


def _adjoint(T: np.ndarray) -> np.ndarray:
    """(F,6,6) SE(3) adjoints for twists [rho, phi]: [[R, t^ R], [0, R]]."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    out = np.zeros((len(T), 6, 6))
    out[:, :3, :3] = R
    out[:, :3, 3:] = skew(t) @ R
    out[:, 3:, 3:] = R
    return out


def _ad(xi: np.ndarray) -> np.ndarray:
    """(F,6,6) se(3) ad matrices of twists [rho, phi]: [[phi^, rho^], [0, phi^]]."""
    out = np.zeros((len(xi), 6, 6))
    P = skew(xi[:, 3:])
    out[:, :3, :3] = P
    out[:, :3, 3:] = skew(xi[:, :3])
    out[:, 3:, 3:] = P
    return out


def _concat(parts: list[np.ndarray], empty: np.ndarray) -> np.ndarray:
    return np.concatenate(parts) if parts else empty


class GraphProblem:
    """Residuals f(x) and Jacobian J(x) (dense) of one solve; node states are frozen copies.

    Args:
        R0: (N,3,3) rotations R_MS of the nodes at the start; t0: (N,3) translations (m); lam0: (N,).
        free: (N,) bool, False for fixed nodes; lam_ref: the scale priors' centre (the first node's lambda_0).
        odometry, points, scales: factors whose a, b are node positions 0..N-1 (not node ids).
    """

    def __init__(self, R0: np.ndarray, t0: np.ndarray, lam0: np.ndarray, free: np.ndarray, lam_ref: float,
                 odometry: list[OdometryFactor], points: list[PointGroup], scales: list[ScaleFactor],
                 cfg: GraphConfig, lam_only: int | None = None) -> None:
        self.R0, self.t0, self.lam0 = R0, t0, lam0
        self.k = float(cfg.huber_threshold)
        free = np.asarray(free, bool)
        self.free_pos = np.flatnonzero(free)
        self.n_params = NODE_PARAMS * len(self.free_pos)
        # colmap[i, k]: the column of node i's parameter k (-1: not estimated); lam_only: a fixed-pose node
        # whose lambda is estimated (the gauge with GraphConfig.gauge_lambda_free), one column at the end
        self.colmap = np.full((len(free), NODE_PARAMS), -1)
        self.colmap[self.free_pos] = np.arange(self.n_params).reshape(-1, NODE_PARAMS)
        self.lam_only = lam_only
        if lam_only is not None:
            if free[lam_only]:
                raise ValueError(f"node position {lam_only} is free: lam_only is for a fixed-pose node")
            self.colmap[lam_only, 4] = self.n_params
            self.n_params += 1
        self.lam_pos = np.flatnonzero(self.colmap[:, 4] >= 0)
        """Positions of the nodes whose lambda is estimated (each gets the scale prior)."""
        # odometry
        self.o_a = np.array([f.a for f in odometry], int)
        self.o_b = np.array([f.b for f in odometry], int)
        Z = np.array([f.Z_ab for f in odometry]).reshape(-1, 4, 4)
        self.o_Zinv = se3_inverse(Z) if len(Z) else Z
        self.o_W = np.array([odometry_weights(f.Z_ab, cfg) for f in odometry]).reshape(-1, 6)
        # points, concatenated over groups; whitening frozen at the start state
        cat = _concat
        self.p_a = cat([g.p_a for g in points], np.zeros((0, 3)))
        self.p_b = cat([g.p_b for g in points], np.zeros((0, 3)))
        self.p_ia = cat([np.full(g.n, g.a, int) for g in points], np.zeros(0, int))
        self.p_ib = cat([np.full(g.n, g.b, int) for g in points], np.zeros(0, int))
        self.p_g = cat([np.full(g.n, np.sqrt(1.0 / g.n)) for g in points], np.zeros(0))
        Pa = np.exp(lam0[self.p_ia])[:, None] * self.p_a
        Pb = np.exp(lam0[self.p_ib])[:, None] * self.p_b
        self.p_W = (point_whitening(R0[self.p_ia], Pa, R0[self.p_ib], Pb, cfg) if len(Pa)
                    else np.zeros((0, 3, 3)))
        # scale prior on every estimated lambda (free nodes, and the gauge's when free), centred on lam_ref
        self.prior_sigma = float(cfg.scale_prior_sigma)
        self.lam_ref = float(lam_ref)
        # scale links
        self.s_a = np.array([f.a for f in scales], int)
        self.s_b = np.array([f.b for f in scales], int)
        self.s_kappa = np.array([f.kappa for f in scales], float)
        self.s_sigma = np.array([f.sigma for f in scales], float)
        n_o, n_p, n_f, n_s = len(self.o_a), len(self.p_a), len(self.lam_pos), len(self.s_a)
        self.row_o = 0
        self.row_p = 6 * n_o
        self.row_prior = self.row_p + 3 * n_p
        self.row_s = self.row_prior + n_f
        self.n_residuals = self.row_s + n_s
        # blocks, in row order: odometry, points, priors, links
        sizes = [np.full(n_o, 6), np.full(n_p, 3), np.ones(n_f + n_s, int)]
        self.block = np.repeat(np.arange(n_o + n_p + n_f + n_s), np.concatenate(sizes).astype(int))
        g = np.ones(n_o + n_p + n_f + n_s)
        g[n_o:n_o + n_p] = self.p_g ** 2
        self.loss = BlockHuber(self.block, g, self.k)
        self._cache_x: np.ndarray | None = None
        self._cache: tuple[np.ndarray, np.ndarray] | None = None

    # --- states --------------------------------------------------------------------------------
    def states(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R (N,3,3), t (N,3), lam (N,)) of all nodes at parameters x."""
        R, t, lam = self.R0.copy(), self.t0.copy(), self.lam0.copy()
        x = np.asarray(x, np.float64)
        if len(self.free_pos):
            X = x[:NODE_PARAMS * len(self.free_pos)].reshape(-1, NODE_PARAMS)
            fp = self.free_pos
            R[fp] = rot_z(X[:, 3]) @ self.R0[fp]
            t[fp] = self.t0[fp] + X[:, :3]
            lam[fp] = self.lam0[fp] + X[:, 4]
        if self.lam_only is not None:
            lam[self.lam_only] = self.lam0[self.lam_only] + x[-1]
        return R, t, lam

    # --- evaluation ----------------------------------------------------------------------------
    def residual(self, x: np.ndarray) -> np.ndarray:
        """(m,) whitened residual rows at x (a copy: scipy rescales what it gets in place)."""
        return self._evaluate(x)[0].copy()

    def jacobian(self, x: np.ndarray) -> csr_matrix:
        """(m, n) sparse (CSR) Jacobian of `residual` at x (a copy)."""
        return self._evaluate(x)[1].copy()

    def cost(self, x: np.ndarray) -> float:
        """The objective E (eq. objective): sum of rho over block norms, point blocks weighted 1/N_ab."""
        return self.loss.cost(self.residual(x))

    def _evaluate(self, x: np.ndarray) -> tuple[np.ndarray, csr_matrix]:
        x = np.asarray(x, np.float64)
        if self._cache_x is not None and np.array_equal(x, self._cache_x):
            return self._cache
        R, t, lam = self.states(x)
        f = np.zeros(self.n_residuals)
        J: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []     # (rows, cols, values) triplets
        self._odometry(R, t, f, J)
        self._points(R, t, lam, f, J)
        self._scalars(lam, f, J)
        if J:
            r, c, v = (np.concatenate([part[i].ravel() for part in J]) for i in range(3))
        else:
            r, c, v = np.zeros(0, int), np.zeros(0, int), np.zeros(0)
        Jm = csr_matrix((v, (r, c)), shape=(self.n_residuals, self.n_params))   # duplicates are summed
        self._cache_x, self._cache = x.copy(), (f, Jm)
        return f, Jm

    def _put(self, J: list, rows: np.ndarray, node: np.ndarray, blocks: np.ndarray, cols: slice) -> None:
        """Add blocks (B, d, c) at rows (B, d) and the columns `cols` of each block's node."""
        idx = np.broadcast_to(self.colmap[node][:, cols][:, None, :], blocks.shape)
        ok = idx >= 0
        if not np.any(ok):
            return
        J.append((np.broadcast_to(rows[:, :, None], blocks.shape)[ok], idx[ok], blocks[ok]))

    def _odometry(self, R: np.ndarray, t: np.ndarray, f: np.ndarray, J: list) -> None:
        n = len(self.o_a)
        if n == 0:
            return
        Q = make_pose(R, t)
        Qa, Qb = Q[self.o_a], Q[self.o_b]
        P = se3_inverse(Qa) @ Qb                       # T_SaSb predicted by the graph
        r = se3_log(self.o_Zinv @ P)                   # (n,6) [rho (m), phi (rad)]
        rows = self.row_o + 6 * np.arange(n)[:, None] + np.arange(6)
        f[rows] = self.o_W * r
        # dr/dxi_b = Jr^-1(r) ~ I + ad/2 + ad^2/12 (ad = ad(r), series) for Q_b Exp(xi_b);
        # dr/dxi_a = -Jr^-1(r) Ad(P^-1); a free node's (dt, dyaw) maps to xi = [R^T dt, R^T e_z dyaw].
        ad = _ad(r)
        Jinv = np.eye(6) + 0.5 * ad + (ad @ ad) / 12.0
        WJ = self.o_W[:, :, None] * Jinv
        for node, sign, pre in ((self.o_b, 1.0, None), (self.o_a, -1.0, _adjoint(se3_inverse(P)))):
            G = np.zeros((n, 6, 4))
            Rt = np.swapaxes(R[node], 1, 2)
            G[:, :3, :3] = Rt
            G[:, 3:, 3] = Rt @ _EZ
            if pre is not None:
                G = pre @ G
            self._put(J, rows, node, sign * (WJ @ G), slice(0, 4))

    def _points(self, R: np.ndarray, t: np.ndarray, lam: np.ndarray, f: np.ndarray, J: list) -> None:
        n = len(self.p_a)
        if n == 0:
            return
        ia, ib = self.p_ia, self.p_ib
        A = np.einsum("nij,nj->ni", R[ia], np.exp(lam[ia])[:, None] * self.p_a)
        B = np.einsum("nij,nj->ni", R[ib], np.exp(lam[ib])[:, None] * self.p_b)
        r = A + t[ia] - B - t[ib]
        rows = self.row_p + 3 * np.arange(n)[:, None] + np.arange(3)
        M = self.p_g[:, None, None] * self.p_W
        f[rows] = np.einsum("nij,nj->ni", M, r)
        for node, sign, X in ((ia, 1.0, A), (ib, -1.0, B)):
            G = np.zeros((n, 3, NODE_PARAMS))
            G[:, :3, :3] = np.eye(3)
            G[:, :, 3] = np.cross(_EZ, X)               # d(Rz(dyaw) X)/d dyaw = e_z x X
            G[:, :, 4] = X                              # d(e^lam X)/d lam = X
            self._put(J, rows, node, sign * (M @ G), slice(0, NODE_PARAMS))

    def _scalars(self, lam: np.ndarray, f: np.ndarray, J: list) -> None:
        lp = self.lam_pos
        if len(lp):
            rows = self.row_prior + np.arange(len(lp))
            f[rows] = (lam[lp] - self.lam_ref) / self.prior_sigma
            J.append((rows, self.colmap[lp, 4], np.full(len(lp), 1.0 / self.prior_sigma)))
        if len(self.s_a):
            rows = self.row_s + np.arange(len(self.s_a))
            f[rows] = (lam[self.s_b] - lam[self.s_a] - self.s_kappa) / self.s_sigma
            d = 1.0 / self.s_sigma
            for node, sign in ((self.s_b, 1.0), (self.s_a, -1.0)):
                c = self.colmap[node, 4]
                ok = c >= 0
                J.append((rows[ok], c[ok], sign * d[ok]))
