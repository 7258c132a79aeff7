"""Shape checks shared by the geometry functions, and the geometry error type."""
from __future__ import annotations

import numpy as np

from runtime.errors import DavioError


class GeometryError(DavioError, ValueError):
    """An array handed to a geometry function has the wrong shape or an invalid value."""


def as_vectors(x: object, name: str, size: int = 3) -> np.ndarray:
    """`x` as a finite float64 array whose last axis has length `size`; raises GeometryError otherwise."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != size:
        raise GeometryError(f"{name} must have shape (..., {size}), got {a.shape}")
    if not np.isfinite(a).all():
        raise GeometryError(f"{name} holds non-finite values")
    return a


def as_matrices(x: object, name: str, size: int = 3) -> np.ndarray:
    """`x` as a finite float64 array of shape (..., size, size); raises GeometryError otherwise."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim < 2 or a.shape[-2:] != (size, size):
        raise GeometryError(f"{name} must have shape (..., {size}, {size}), got {a.shape}")
    if not np.isfinite(a).all():
        raise GeometryError(f"{name} holds non-finite values")
    return a
