"""Limit the BLAS thread pools (numpy's and scipy's OpenBLAS) for the filter's small matrices.

Matrices of a few hundred rows run fastest single-threaded; with threads, a shared 2-core machine spends
most of its time in spinning BLAS workers (measured: 40 ms instead of 0.2 ms per EKF update).
The pools are process-wide, so this is applied once, by the estimator when its config asks for it.
"""
from __future__ import annotations

_applied: object | None = None


def limit_blas_threads(n: int) -> bool:
    """Set the BLAS pools to n threads (needs threadpoolctl; False when it is not installed)."""
    global _applied
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return False
    import scipy.linalg  # noqa: F401  (load scipy's own OpenBLAS so that it is limited too)

    _applied = threadpool_limits(limits=int(n), user_api="blas")
    return True
