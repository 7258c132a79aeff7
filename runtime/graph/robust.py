"""The Huber loss of the graph objective (paper eq. objective) on whitened residual blocks.

rho(r) = r^2 / 2 for r <= k and k r - k^2 / 2 beyond (k = 2 in the paper: 2 r - 2), where r >= 0 is
the norm of one whitened block (a 6-vector odometry residual, a 3-vector point residual, a scalar
scale residual). Its IRLS weight is w(r) = rho'(r) / r = min(1, k / r).

How the solver uses it (exact, on block norms): scipy's least_squares (method "trf") takes a callable
`loss(z)` that receives the squares z_i = f_i^2 of ALL residual components at once and returns, per
component, (rho_i, rho'_i, rho''_i); scipy's cost is 1/2 sum rho_i. `BlockHuber` sums z over each block
to get the block norm n (undoing the point-group weight g = 1/N_ab: z sums to g n^2) and returns

    rho_i = z_i                        if n <= k   (so 1/2 sum_block rho_i = g n^2 / 2 = g rho(n))
    rho_i = 2 g rho(n) z_i / (g n^2)   if n > k    (so 1/2 sum_block rho_i = g rho(n)),
    rho'_i = w(n) = rho'(n) / n,  rho''_i = 0.

Hence scipy's cost is exactly E, its gradient J^T (rho' f) is exactly dE/dx, and its model Hessian
J^T diag(w) J is the IRLS one: the robust weights are recomputed at every accepted step, i.e. this is
IRLS inside the trust-region (Levenberg-Marquardt) iteration, with the exact Huber objective deciding
whether a step is accepted.
"""
from __future__ import annotations

import numpy as np


def huber_rho(r: np.ndarray | float, k: float = 2.0) -> np.ndarray:
    """rho(r) of block norms r >= 0 (whitened, unitless): r^2/2 up to k, k r - k^2/2 beyond."""
    r = np.asarray(r, np.float64)
    if np.isinf(k):
        return 0.5 * r * r
    return np.where(r <= k, 0.5 * r * r, k * r - 0.5 * k * k)


def huber_weight(r: np.ndarray | float, k: float = 2.0) -> np.ndarray:
    """The IRLS weight rho'(r) / r = min(1, k / r) of block norms r >= 0 (1 at r = 0)."""
    r = np.asarray(r, np.float64)
    return np.where(r <= k, 1.0, k / np.where(r > k, r, 1.0))


class BlockHuber:
    """scipy `loss` callable applying huber_rho to the norm of each residual block (see module doc).

    Args:
        block: (m,) block index of every residual row (0 .. B-1, rows of one block contiguous or not).
        g: (B,) weight of each block in the objective (1/N_ab for point blocks, 1 otherwise); the
            residual rows of block b carry sqrt(g_b).
        k: Huber threshold on the whitened block norm.
    """

    def __init__(self, block: np.ndarray, g: np.ndarray, k: float) -> None:
        self.block = np.asarray(block, np.int64)
        self.g = np.asarray(g, np.float64)
        self.k = float(k)

    def block_norms(self, z: np.ndarray) -> np.ndarray:
        """(B,) whitened block norms n_b from the squared residual rows z (m,)."""
        Z = np.bincount(self.block, weights=z, minlength=len(self.g))
        return np.sqrt(Z / self.g)

    def cost(self, f: np.ndarray) -> float:
        """E = sum_b g_b rho(n_b) of the residual rows f (m,)."""
        return float(self.g @ huber_rho(self.block_norms(f * f), self.k))

    def __call__(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, np.float64)
        n = self.block_norms(z)
        out = np.zeros((3, len(z)))
        out[0] = z
        out[1] = huber_weight(n, self.k)[self.block]
        big = (n > self.k)[self.block]
        if np.any(big):
            gn2 = self.g * n * n
            ratio = 2.0 * self.g * huber_rho(n, self.k) / np.where(gn2 > 0, gn2, 1.0)
            out[0, big] = z[big] * ratio[self.block[big]]
        return out
