"""Vertex positions of PLY files (ascii, binary little/big endian), read with numpy only.

Only the `vertex` element's x, y, z properties are returned; other elements that follow the
vertices (faces) are ignored. Malformed headers or short bodies raise `DataError`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from runtime.errors import DataError

_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply_vertices(path: str | Path) -> np.ndarray:
    """(N, 3) float64 vertex positions of a PLY file."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read PLY file: {exc.strerror or exc}", path) from exc
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise DataError("not a PLY file (missing 'ply' magic or 'end_header')", path)
    body_start = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for lineno, line in enumerate(header, start=1):
        parts = line.split()
        if not parts or parts[0] in ("ply", "comment", "obj_info"):
            continue
        if parts[0] == "format":
            fmt = parts[1] if len(parts) > 1 else None
        elif parts[0] == "element" and len(parts) == 3 and parts[2].isdigit():
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property" and elements:
            if parts[1] == "list":
                if elements[-1][0] == "vertex":
                    raise DataError("list properties on vertices are not supported", path, lineno)
                elements[-1][2].append((parts[-1], "list"))
            elif parts[1] in _TYPES and len(parts) == 3:
                elements[-1][2].append((parts[2], _TYPES[parts[1]]))
            else:
                raise DataError(f"unknown PLY property type in {line!r}", path, lineno)
        else:
            raise DataError(f"unexpected PLY header line {line!r}", path, lineno)
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DataError(f"unsupported PLY format {fmt!r}", path)
    if not elements or elements[0][0] != "vertex":
        raise DataError("the first PLY element must be 'vertex'", path)
    _, n, props = elements[0]
    names = [p[0] for p in props]
    if not {"x", "y", "z"} <= set(names):
        raise DataError("PLY vertices lack x, y or z", path)
    cols = [names.index(c) for c in ("x", "y", "z")]
    if fmt == "ascii":
        rows = data[body_start:].decode("ascii", errors="replace").splitlines()
        rows = [r for r in rows if r.strip()][:n]
        if len(rows) < n:
            raise DataError(f"PLY body holds {len(rows)} vertex rows, header says {n}", path)
        try:
            table = np.array([r.split()[: len(props)] for r in rows], dtype=np.float64).reshape(n, len(props))
        except ValueError as exc:
            raise DataError(f"malformed PLY vertex row: {exc}", path) from exc
        return table[:, cols].copy()
    order = "<" if fmt == "binary_little_endian" else ">"
    dtype = np.dtype([(name, order + t) for name, t in props])
    if len(data) - body_start < n * dtype.itemsize:
        raise DataError(f"PLY body is truncated: {len(data) - body_start} bytes for {n} vertices "
                        f"of {dtype.itemsize} bytes", path)
    verts = np.frombuffer(data, dtype=dtype, count=n, offset=body_start)
    return np.stack([verts[c].astype(np.float64) for c in ("x", "y", "z")], axis=1)
