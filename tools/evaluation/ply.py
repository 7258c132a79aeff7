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


def _split_header(data: bytes, path: Path) -> tuple[list[str], int]:
    """(header lines before end_header, offset of the first body byte) of a PLY file's bytes."""
    if not (data.startswith(b"ply\n") or data.startswith(b"ply\r\n")):
        raise DataError("not a PLY file (the first line must be 'ply')", path)
    pos = 0
    while True:
        nl = data.find(b"\n", pos)
        line = data[pos:] if nl < 0 else data[pos:nl]
        if line.strip() == b"end_header":
            header = data[:pos].decode("ascii", errors="replace").splitlines()
            return header, len(data) if nl < 0 else nl + 1
        if nl < 0:
            raise DataError("PLY header has no 'end_header' line (truncated file, or not a PLY file)", path)
        pos = nl + 1


def _parse_header(header: list[str], path: Path) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]]]:
    """(format, [(element name, count, [(property name, numpy type or 'list')])]) of the header lines."""
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for lineno, line in enumerate(header, start=1):
        parts = line.split()
        if not parts or parts[0] in ("ply", "comment", "obj_info"):
            continue
        if parts[0] == "format" and len(parts) in (2, 3):
            fmt = parts[1]
        elif parts[0] == "element" and len(parts) == 3 and parts[2].isascii() and parts[2].isdigit():
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property" and elements and len(parts) >= 3:
            props = elements[-1][2]
            if parts[-1] in [name for name, _ in props]:
                raise DataError(f"property {parts[-1]!r} appears twice in element {elements[-1][0]!r}",
                                path, lineno)
            if parts[1] == "list" and len(parts) == 5:
                if elements[-1][0] == "vertex":
                    raise DataError("list properties on vertices are not supported", path, lineno)
                props.append((parts[-1], "list"))
            elif parts[1] in _TYPES and len(parts) == 3:
                props.append((parts[2], _TYPES[parts[1]]))
            else:
                raise DataError(f"unknown PLY property type in {line!r}", path, lineno)
        else:
            raise DataError(f"unexpected PLY header line {line!r}", path, lineno)
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DataError(f"unsupported PLY format {fmt!r}", path)
    return fmt, elements


def ply_comments(path: str | Path, max_bytes: int = 65536) -> list[str]:
    """The header's comment lines of a PLY file (without "comment "); [] when it is not a readable PLY."""
    try:
        with open(path, "rb") as f:
            head = f.read(max_bytes)
        header, _ = _split_header(head, Path(path))
    except (OSError, DataError):
        return []
    return [line[len("comment "):].strip() for line in header if line.startswith("comment ")]


def read_ply_vertices(path: str | Path) -> np.ndarray:
    """(N, 3) float64 vertex positions of a PLY file; DataError names what is wrong with it."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read PLY file: {exc.strerror or exc}", path) from exc
    header, body_start = _split_header(data, path)
    fmt, elements = _parse_header(header, path)
    if not elements or elements[0][0] != "vertex":
        raise DataError("the first PLY element must be 'vertex'", path)
    _, n, props = elements[0]
    names = [p[0] for p in props]
    if not {"x", "y", "z"} <= set(names):
        raise DataError("PLY vertices lack x, y or z", path)
    if n > 0 and body_start >= len(data):
        raise DataError(f"PLY file ends at end_header: the header declares {n} vertices but no vertex data "
                        "follows (truncated file)", path)
    cols = [names.index(c) for c in ("x", "y", "z")]
    if fmt == "ascii":
        rows = data[body_start:].decode("ascii", errors="replace").splitlines()
        rows = [r for r in rows if r.strip()][:n]
        if len(rows) < n:
            raise DataError(f"PLY body holds {len(rows)} vertex rows, header says {n} (truncated file)", path)
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
