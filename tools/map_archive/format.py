"""Names, schema constants and the strict-JSON helpers of the map archive (atomic writes: runtime.files)."""
from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

FORMAT = "davio-map"
"""Value of the manifest's `format` key."""
SCHEMA_VERSION = 3
"""Schema written by this davio (and the newest it reads). Schema 2 added the journal: a manifest.json
with `journal_generation` G is brought up to date by the lines of manifest.journal written for G.
Schema 3 stores a submap's points as depths and pixels (`RAY_ARRAYS`) where that is exact."""
MIN_SCHEMA_VERSION = 1
"""Oldest schema this davio reads (schema 1: manifest.json alone, no journal)."""
MANIFEST_NAME = "manifest.json"
JOURNAL_NAME = "manifest.journal"
"""The commits since manifest.json was last written whole: one JSON object a line (`MapArchiveWriter`)."""
SUBMAP_RE = re.compile(r"^submap_(\d{6,})\.npz$")
"""Names of submap files (orphans are matched with it)."""
TEMP_RE = re.compile(r"^\.(manifest\.json|submap_\d{6,}\.npz)\..*\.tmp$")
"""Names of temporary files an interrupted write may leave behind."""

ARRAYS: dict[str, str] = {
    "index": "int64", "frame_t_ns": "int64", "centre": "int64", "T_OS": "float64", "T_SC": "float64",
    "K": "float64", "s_hat": "float64", "frame_scales": "float64",
    "image": "uint8", "conf": "float32", "grey": "uint8",
}
"""Arrays every submap .npz holds and their stored dtypes; beside them its points, either `POINTS_ARRAY`
or `RAY_ARRAYS`."""
POINTS_ARRAY = ("points_C", "float32")
"""The points as x, y, z (P,3) in the camera of their image (schemas 1-2, and where rays are not exact)."""
RAY_ARRAYS: dict[str, str] = {"depth": "float32", "pixel_u": "uint16", "pixel_v": "uint16"}
"""The points as depths (P,) along the rays of pixels (pixel_u, pixel_v) (P,) of the submap's K (schema 3;
tools.map_archive.point_rays): about 0.3 MB of a submap's npz where x, y, z took 0.9 MB."""

VIEW_ARRAYS: dict[str, str] = {
    "view_kpts": "float32", "view_scores": "float32", "view_depth": "float32", "view_size": "int64",
}
"""Arrays of a submap's centre view (`Submap.view`), present when the run kept views (the submap graph
on): keypoints (pixels of the rectified centre image, whose K is the submap's), detection scores,
corrected depths at the keypoints (m, NaN where none) and the image size (width, height). Beside them
`view_desc` (float16 for float descriptors, uint8 for binary ones) and, for pyramid features,
`view_level` (int8). Archives written before views were stored lack them all; readers that do not
know them ignore them (the schema is unchanged)."""


def submap_filename(index: int) -> str:
    """File name of submap `index` (e.g. submap_000012.npz)."""
    return f"submap_{int(index):06d}.npz"


def davio_version() -> str:
    """'davio X.Y.Z' of the installed package ('davio unknown' when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"davio {version('davio')}"
    except PackageNotFoundError:
        return "davio unknown"


def jsonable(x: Any) -> Any:
    """`x` as strict-JSON data: numpy scalars and arrays to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [jsonable(v) for v in (x.tolist() if isinstance(x, np.ndarray) else x)]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if x is None or isinstance(x, str):
        return x
    return str(x)
