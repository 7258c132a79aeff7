"""Strict JSON for everything DAVIO prints or writes: no `NaN` / `Infinity` tokens (RFC 8259).

Non-finite floats become null, numpy scalars and arrays become Python numbers and lists, paths and
other objects become their string form. Python's `json.dumps` writes `NaN`, which `jq`, browsers and
most JSON libraries refuse.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any


def jsonable(obj: Any) -> Any:
    """`obj` with every non-finite float replaced by None and numpy values made plain Python."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | set | frozenset):
        return [jsonable(v) for v in obj]
    try:
        import numpy as np
    except ImportError:  # pragma: no cover - numpy is a dependency
        np = None
    if np is not None:
        if isinstance(obj, np.ndarray):
            return jsonable(obj.tolist())
        if isinstance(obj, np.bool_):
            return bool(obj)
        if isinstance(obj, np.integer):
            return int(obj)
        if isinstance(obj, np.floating):
            return jsonable(float(obj))
    if isinstance(obj, Path):
        return str(obj)
    return str(obj)


def strict_dumps(obj: Any, **kwargs: Any) -> str:
    """`json.dumps` of `jsonable(obj)` with `allow_nan=False` (kwargs such as indent pass through)."""
    kwargs.pop("default", None)
    return json.dumps(jsonable(obj), allow_nan=False, **kwargs)
