"""Finite-difference Jacobians with a known sparsity pattern (one evaluation pair per column group)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse


def group_columns(S: scipy.sparse.csc_matrix) -> np.ndarray:
    """(n,) group index per column such that no two columns of a group share a non-zero row.

    Greedy in column order: each column joins the first group it does not overlap, else opens one.
    """
    n_rows, n = S.shape
    groups = np.full(n, -1, dtype=int)
    used: list[np.ndarray] = []
    for c in range(n):
        rr = S.indices[S.indptr[c] : S.indptr[c + 1]]
        for gi, mask in enumerate(used):
            if not mask[rr].any():
                mask[rr] = True
                groups[c] = gi
                break
        else:
            mask = np.zeros(n_rows, dtype=bool)
            mask[rr] = True
            used.append(mask)
            groups[c] = len(used) - 1
    return groups


def sparse_fd_jacobian(
    fun: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    S: scipy.sparse.spmatrix,
    step: float = 1e-7,
) -> scipy.sparse.csr_matrix:
    """Central finite-difference Jacobian d fun / d x at x, restricted to the sparsity pattern S.

    Args:
        fun: residual function R^n -> R^m (any units; the Jacobian has fun's units per x's).
        x: (n,) point.
        S: (m, n) pattern; entries outside it are taken as zero (and must be, for exact grouping).
        step: relative step, h = step * max(1, |x_j|).

    Columns that share no row are perturbed together (:func:`group_columns`), so the cost is two
    evaluations per group instead of per column.
    """
    S = scipy.sparse.csc_matrix(S)
    n = x.size
    groups = group_columns(S)
    rows_all, cols_all, vals_all = [], [], []
    for gidx in np.unique(groups):
        cols = np.flatnonzero(groups == gidx)
        h = step * np.maximum(1.0, np.abs(x[cols]))
        xp = x.copy()
        xm = x.copy()
        xp[cols] += h
        xm[cols] -= h
        diff = fun(xp) - fun(xm)
        for c, hc in zip(cols, h, strict=True):
            rr = S.indices[S.indptr[c] : S.indptr[c + 1]]
            rows_all.append(rr)
            cols_all.append(np.full(rr.size, c))
            vals_all.append(diff[rr] / (2.0 * hc))
    return scipy.sparse.csr_matrix(
        (np.concatenate(vals_all), (np.concatenate(rows_all), np.concatenate(cols_all))),
        shape=(S.shape[0], n),
    )
