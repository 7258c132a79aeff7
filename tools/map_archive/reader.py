"""Reading the map archive: manifest checks, file integrity, submaps back as `Submap` objects."""
from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from calib.rig import rigid_problem
from runtime.errors import DataError
from runtime.files import sha256_file
from runtime.mapping.submap import Submap
from tools.map_archive.format import (
    ARRAYS,
    FORMAT,
    JOURNAL_NAME,
    MANIFEST_NAME,
    MIN_SCHEMA_VERSION,
    POINTS_ARRAY,
    RAY_ARRAYS,
    SCHEMA_VERSION,
    SUBMAP_RE,
    TEMP_RE,
    VIEW_ARRAYS,
)
from tools.map_archive.point_rays import decode_rays

_ENTRY_KEYS = ("index", "file", "sha256", "bytes", "n_points", "T_MS", "lam", "version")
_INT_KEYS = ("index", "bytes", "n_points", "version")
_SCALAR_ARRAYS = ("index", "centre", "s_hat")


def read_manifest(folder: str | Path) -> dict:
    """The manifest of the archive in `folder`, after checking its format and schema, brought up to date
    by its journal (schema 2; `MapArchiveWriter`). `info["journal"]` says what the journal held:
    {"commits": lines applied, "stale": lines of an older generation skipped, "incomplete_bytes": the
    length of a last line cut short (a run killed while writing it; that commit is lost)}.

    Raises:
        DataError: missing folder or manifest, not JSON, foreign format, unsupported schema, a damaged
            journal line, or a submap entry lacking a key (each naming the file).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError("map archive folder not found", folder)
    path = folder / MANIFEST_NAME
    if not path.is_file():
        raise DataError("no manifest.json: not a davio map archive, or the run stopped before its first "
                        "map commit", path)
    for _ in range(_READ_TRIES):      # a run writing the archive may rewrite manifest.json meanwhile
        info = _read_whole(path)
        _check_entries(info, path)
        journal = _apply_journal(folder / JOURNAL_NAME, info)
        if journal is not None:
            break
    else:
        gen = info.get("journal_generation")
        raise DataError(f"the archive changed {_READ_TRIES} times while it was read: its lines are of a "
                        f"later generation than manifest.json's ({gen}). A run writing it: try again. "
                        "Otherwise manifest.json is an older copy than the journal (a copy of a running "
                        "archive, a restored backup): copy the matching manifest.json, or remove "
                        "manifest.journal to read manifest.json as it is (its commits are lost)",
                        folder / JOURNAL_NAME)
    if journal["commits"]:
        _check_entries(info, folder / JOURNAL_NAME)
    info["journal"] = journal
    return info


_READ_TRIES = 5


def _read_whole(path: Path) -> dict:
    """manifest.json parsed, its format and schema checked."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise DataError(f"manifest unreadable: {exc.strerror or exc}", path) from exc
    try:
        info = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise DataError(f"manifest is not valid JSON: {exc}", path) from exc
    if not isinstance(info, dict) or info.get("format") != FORMAT:
        fmt = info.get("format") if isinstance(info, dict) else None
        if fmt is None:
            raise DataError(f"foreign archive: this manifest.json has no 'format' key (expected {FORMAT!r}): "
                            "not a davio map archive", path)
        raise DataError(f"foreign archive: format is {fmt!r}, expected {FORMAT!r}", path)
    schema = info.get("schema_version")
    if not isinstance(schema, int) or isinstance(schema, bool):
        raise DataError(f"schema_version is {schema!r}, expected an integer", path)
    if schema > SCHEMA_VERSION:
        raise DataError(f"written by a newer davio ({info.get('created_by', '?')}); needs schema {schema} "
                        f"support, this davio reads schemas {MIN_SCHEMA_VERSION}..{SCHEMA_VERSION}", path)
    if schema < MIN_SCHEMA_VERSION:
        raise DataError(f"schema {schema} is no longer supported (this davio reads schemas "
                        f"{MIN_SCHEMA_VERSION}..{SCHEMA_VERSION}); needs a davio with schema {schema} "
                        "support", path)
    if schema >= 2:
        gen = info.get("journal_generation")
        if not isinstance(gen, int) or isinstance(gen, bool) or gen < 1:
            raise DataError(f"journal_generation is {gen!r}, expected an integer >= 1", path)
    if not isinstance(info.get("submaps"), list):
        raise DataError("manifest lacks the 'submaps' list", path)
    if info.get("pairs") is not None and not isinstance(info["pairs"], list):
        raise DataError(f"'pairs' is {info['pairs']!r}, expected a list", path)
    return info


def _apply_journal(path: Path, info: dict) -> dict | None:
    """Apply the journal's lines of the manifest's generation to `info` (in place); returns what it held,
    or None when a line belongs to a newer manifest.json than `info` (written meanwhile: read again)."""
    out = {"commits": 0, "stale": 0, "incomplete_bytes": 0}
    gen = info.get("journal_generation")
    if gen is None or not path.is_file():
        return out
    try:
        data = path.read_bytes()
    except FileNotFoundError:             # removed by a whole write since is_file(): read manifest.json again
        return None
    except OSError as exc:
        raise DataError(f"journal unreadable: {exc}", path) from exc
    lines = data.split(b"\n")
    out["incomplete_bytes"] = len(lines.pop())    # after the last newline: a line the writer did not finish
    entries = {e["index"]: e for e in info["submaps"]}     # checked by _check_entries
    pairs = list(info.get("pairs") or [])
    for no, raw in enumerate(lines, start=1):
        rec = _journal_record(raw, no, path)
        if rec["generation"] > gen:
            return None
        if rec["generation"] < gen:               # written before manifest.json was last written whole
            out["stale"] += 1
            continue
        if rec["pairs_keep"] > len(pairs):
            raise DataError(f"line {no} keeps {rec['pairs_keep']} pair records of {len(pairs)}", path)
        for k, e in enumerate(rec["submaps"]):
            idx = e.get("index") if isinstance(e, dict) else None
            if not _is_int(idx):
                raise DataError(f"line {no}: submaps[{k}] has no integer index", path)
            if idx not in entries:
                missing = [key for key in _ENTRY_KEYS if key not in e]
                if missing:
                    raise DataError(f"line {no}: new submap {idx} lacks {', '.join(missing)}", path)
                entries[idx] = dict(e)
            else:
                entries[idx].update(e)
        del pairs[rec["pairs_keep"]:]
        pairs.extend(rec["pairs"])
        info.update(map_version=rec["map_version"], stats=rec["stats"])
        out["commits"] += 1
    if out["commits"]:
        info["submaps"] = [entries[k] for k in sorted(entries)]
        info["pairs"] = pairs
    return out


_RECORD_TYPES = {"generation": int, "map_version": int, "submaps": list, "pairs_keep": int, "pairs": list,
                 "stats": dict}


def _journal_record(raw: bytes, no: int, path: Path) -> dict:
    """Journal line `no`, parsed and its keys type-checked."""
    try:
        rec = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise DataError(f"line {no} is not valid JSON ({exc}): the journal is damaged", path) from exc
    if not isinstance(rec, dict):
        raise DataError(f"line {no} is not a JSON object: the journal is damaged", path)
    for key, typ in _RECORD_TYPES.items():
        value = rec.get(key)
        if not isinstance(value, typ) or isinstance(value, bool) or (typ is int and value < 0):
            raise DataError(f"line {no}: {key} is {value!r}, expected "
                            f"{'a non-negative integer' if typ is int else 'a ' + typ.__name__}", path)
    return rec


def _is_int(x: object) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _check_entries(info: dict, path: Path) -> None:
    """Every submap entry has the keys and types the readers use, and names its own index and file."""
    seen: dict[object, int] = {}
    for k, e in enumerate(info["submaps"]):
        missing = [key for key in _ENTRY_KEYS if not isinstance(e, dict) or key not in e]
        if missing:
            raise DataError(f"submaps[{k}] lacks {', '.join(missing)}", path)
        bad = [key for key in _INT_KEYS if not isinstance(e[key], int) or isinstance(e[key], bool)]
        if bad:
            raise DataError(f"submaps[{k}].{bad[0]} is {e[bad[0]]!r}, expected an integer", path)
        if not isinstance(e["file"], str) or not SUBMAP_RE.match(e["file"]):
            raise DataError(f"submaps[{k}].file is {e['file']!r}, expected a name like submap_000000.npz "
                            "inside the archive folder", path)
        for key in (("index", e["index"]), ("file", e["file"])):
            if key in seen:
                raise DataError(f"submaps[{k}] and submaps[{seen[key]}] have the same {key[0]} {key[1]!r}",
                                path)
            seen[key] = k
        segment = e.get("segment", 0)
        if not isinstance(segment, int) or isinstance(segment, bool):
            raise DataError(f"submaps[{k}].segment is {segment!r}, expected an integer", path)
        lam = e["lam"]
        if lam is not None and (not isinstance(lam, (int, float)) or isinstance(lam, bool)):
            raise DataError(f"submaps[{k}].lam is {lam!r}, expected a number (or null)", path)
        if e.get("fit") is not None and not isinstance(e["fit"], dict):
            raise DataError(f"submaps[{k}].fit is {e['fit']!r}, expected an object (or null)", path)


MAX_ABS_LAM = 5.0
"""Largest |lam| (log depth scale) a usable graph state holds: a factor of 148 on depth."""
MAX_TRANSLATION_M = 1e7
"""Largest submap translation a usable graph state holds (ten times the Earth's radius)."""


def state_problem(entry: dict) -> str | None:
    """Why a manifest entry's graph state (T_MS, lam) cannot place its points, or None when it can: null
    (the writer's non-finite state), NaN or Inf (a hand-edited file: JSON readers accept them), or a T_MS
    that is not a 4x4 rigid transform (a collapsed map, or a failure inside the relocalizer)."""
    lam = entry["lam"]
    if lam is None:
        return "lam is null (not finite when written)"
    try:
        lam_ok = np.isfinite(float(lam)) and abs(float(lam)) <= MAX_ABS_LAM
    except (TypeError, OverflowError):     # an integer beyond a float's range
        lam_ok = False
    if not lam_ok:
        return f"lam is {lam!r}, not a finite log scale within +-{MAX_ABS_LAM:g}"
    problem = rigid_problem(entry["T_MS"])     # a null in T_MS (non-finite when written) reads as NaN
    if problem is not None:
        return f"T_MS: {problem}"
    if np.abs(np.array(entry["T_MS"], np.float64)[:3, 3]).max() > MAX_TRANSLATION_M:
        return f"T_MS: translation beyond {MAX_TRANSLATION_M:g} m"
    return None


def state_is_usable(entry: dict) -> bool:
    """Whether a manifest entry's graph state places its points (`state_problem` finds nothing)."""
    return state_problem(entry) is None


def integrity(folder: str | Path, manifest: dict | None = None) -> tuple[list[str], list[str]]:
    """(problems, orphans) of the archive: each referenced file against the manifest's size and
    sha256; orphans are submap or temporary files the manifest does not reference (left by an
    interrupted commit; harmless). Each line starts with the file name."""
    folder = Path(folder)
    info = read_manifest(folder) if manifest is None else manifest
    problems, referenced = [], set()
    for e in info["submaps"]:
        name = str(e["file"])
        referenced.add(name)
        path = folder / name
        if not path.is_file():
            problems.append(f"{name}: missing (submap {e['index']})")
            continue
        try:
            size = path.stat().st_size
            if size != e["bytes"]:
                problems.append(f"{name}: {size} bytes, the manifest says {e['bytes']} (truncated or "
                                "replaced)")
            elif sha256_file(path) != e["sha256"]:
                problems.append(f"{name}: sha256 differs from the manifest (damaged or edited)")
        except OSError as exc:
            problems.append(f"{name}: unreadable ({exc.strerror or exc})")
    try:
        stray = [p for p in sorted(folder.iterdir()) if p.name not in referenced and p.is_file()
                 and (SUBMAP_RE.match(p.name) or TEMP_RE.match(p.name))]
    except OSError as exc:
        raise DataError(f"the archive folder cannot be listed: {exc.strerror or exc}", folder) from exc
    orphans = [f"{p.name}: orphan, not referenced by the manifest (left by an interrupted commit; harmless)"
               for p in stray]
    return problems, orphans


def check_integrity(folder: str | Path) -> list[str]:
    """Problems, then orphan notes (which say 'orphan'), of the archive in `folder`; empty when clean."""
    problems, orphans = integrity(folder)
    return problems + orphans


def _matrix(value: object, shape: tuple[int, ...], what: str, path: Path) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)  # null (non-finite when written) reads as NaN
    except (TypeError, ValueError, OverflowError) as exc:
        raise DataError(f"{what} is not numeric: {exc}", path) from exc
    if a.shape != shape:
        raise DataError(f"{what} has shape {a.shape}, expected {shape}", path)
    return a


def _scale(lam: object) -> float:
    """A manifest's lam as a float: NaN for null (non-finite when written) and for an integer beyond a
    float's range (`state_problem` names both)."""
    try:
        return float("nan") if lam is None else float(lam)    # type: ignore[arg-type]
    except OverflowError:
        return float("nan")


def load_submap(folder: str | Path, entry: dict) -> Submap:
    """The submap of manifest entry `entry`: arrays from its npz, graph state from the entry.

    Raises:
        DataError: missing, truncated or corrupt file, a missing array, or inconsistent shapes.
    """
    path = Path(folder) / str(entry["file"])
    if not path.is_file():
        raise DataError(f"submap file missing (submap {entry['index']})", path)
    arrays = {}
    try:
        with np.load(path, allow_pickle=False) as npz:
            for name, dtype in ARRAYS.items():
                if name not in npz.files:
                    raise DataError(f"array {name!r} missing from the submap file", path)
                arrays[name] = npz[name].astype(dtype, copy=False)
            arrays.update(_point_arrays(npz, path))
    except DataError:
        raise
    except Exception as exc:  # damaged zip/npy bytes surface as many types (BadZipFile, zlib, tokenize...)
        raise DataError(f"corrupt or truncated submap file: {type(exc).__name__}: {exc}", path) from exc
    for name in _SCALAR_ARRAYS:
        if arrays[name].size != 1:
            raise DataError(f"array {name!r} holds {arrays[name].size} values, expected one", path)
    K = arrays["K"]
    if K.shape == (3, 3) and not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
        raise DataError(f"K is not a camera matrix (finite, positive focal lengths): {K.tolist()}", path)
    if "points_C" not in arrays:
        depth, u, v = (arrays.pop(n) for n in RAY_ARRAYS)
        if depth.ndim != 1 or u.shape != depth.shape or v.shape != depth.shape or arrays["K"].shape != (3, 3):
            raise DataError(f"inconsistent submap arrays: depth {depth.shape}, pixel_u {u.shape}, "
                            f"pixel_v {v.shape}, K {arrays['K'].shape}", path)
        arrays["points_C"] = decode_rays(depth, u, v, arrays["K"])
    if arrays["T_SC"].ndim != 3 or arrays["points_C"].ndim != 2 or arrays["image"].ndim != 1:
        raise DataError(f"inconsistent submap arrays: T_SC {arrays['T_SC'].shape}, points "
                        f"{arrays['points_C'].shape}, image {arrays['image'].shape}", path)
    n_img, n_pts = len(arrays["T_SC"]), len(arrays["points_C"])
    if n_pts != entry["n_points"]:
        raise DataError(f"the file holds {n_pts} points, the manifest says {entry['n_points']}", path)
    if n_pts and arrays["image"].size == n_pts and int(arrays["image"].max()) >= n_img:
        raise DataError(f"a point's image index is {int(arrays['image'].max())}, the submap has {n_img} "
                        "images", path)
    if int(arrays["index"]) != int(entry["index"]):
        raise DataError(f"file holds submap {int(arrays['index'])}, the manifest says {entry['index']}", path)
    manifest = Path(folder) / MANIFEST_NAME
    T_MS = _matrix(entry["T_MS"], (4, 4), f"submap {entry['index']} T_MS", manifest)
    lam = entry["lam"]
    try:
        return Submap(index=int(entry["index"]), frame_t_ns=arrays["frame_t_ns"],
                      centre=int(arrays["centre"]), T_OS=arrays["T_OS"], T_SC=arrays["T_SC"], K=arrays["K"],
                      s_hat=float(arrays["s_hat"]),
                      frame_scales=arrays["frame_scales"], points_C=arrays["points_C"], image=arrays["image"],
                      conf=arrays["conf"], grey=arrays["grey"], T_MS=T_MS,
                      lam=_scale(lam), version=int(entry["version"]),
                      segment=int(entry.get("segment", 0)), fit=dict(entry.get("fit") or {}))
    except (TypeError, ValueError) as exc:
        raise DataError(f"inconsistent submap arrays: {exc}", path) from exc


def _point_arrays(npz, path: Path) -> dict[str, np.ndarray]:
    """A submap file's points: `points_C` (x, y, z), or `depth`, `pixel_u` and `pixel_v` (schema 3, decoded
    by the caller once K is read)."""
    name, dtype = POINTS_ARRAY
    if name in npz.files:
        return {name: npz[name].astype(dtype, copy=False)}
    missing = [n for n in RAY_ARRAYS if n not in npz.files]
    if missing:
        raise DataError(f"the submap file holds no points: neither array {name!r} nor "
                        f"{', '.join(repr(n) for n in RAY_ARRAYS)}", path)
    return {n: npz[n].astype(dt, copy=False) for n, dt in RAY_ARRAYS.items()}


def iter_submaps(folder: str | Path, manifest: dict | None = None) -> Iterator[Submap]:
    """Every submap of the archive, by index, with its manifest state (loaded one at a time)."""
    info = read_manifest(folder) if manifest is None else manifest
    for e in sorted(info["submaps"], key=lambda e: int(e["index"])):
        yield load_submap(folder, e)


def has_view(folder: str | Path, entry: dict) -> bool:
    """Whether the npz of manifest entry `entry` stores a centre view (reads its file list only)."""
    try:
        with np.load(Path(folder) / str(entry["file"]), allow_pickle=False) as npz:
            return "view_kpts" in npz.files
    except Exception:  # unreadable: load_submap and the integrity check say why
        return False


def load_view(folder: str | Path, entry: dict, compact: bool = False) -> tuple | None:
    """(Features, RevisitView) of the centre image of manifest entry `entry` (descriptors as float32,
    float16 as stored with `compact`, or uint8 when binary), or None when its npz holds no view (an
    archive written without the submap graph, or before views were stored).

    Raises:
        DataError: missing or corrupt file, or view arrays of inconsistent shapes.
    """
    from models.matcher.features import Features
    from runtime.graph.factors import GraphError
    from runtime.graph.revisits import RevisitView

    path = Path(folder) / str(entry["file"])
    if not path.is_file():
        raise DataError(f"submap file missing (submap {entry['index']})", path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            if "view_kpts" not in npz.files:
                return None
            missing = [n for n in (*VIEW_ARRAYS, "view_desc") if n not in npz.files]
            if missing:
                raise DataError(f"centre view incomplete: {', '.join(missing)} missing", path)
            a = {n: npz[n].astype(dt, copy=False) for n, dt in VIEW_ARRAYS.items()}
            desc = npz["view_desc"]
            level = npz["view_level"].astype(np.int8) if "view_level" in npz.files else None
            K = npz["K"].astype(np.float64)
    except DataError:
        raise
    except Exception as exc:  # damaged zip/npy bytes surface as many types
        raise DataError(f"corrupt or truncated submap file: {type(exc).__name__}: {exc}", path) from exc
    n = len(a["view_kpts"])
    if (a["view_kpts"].shape != (n, 2) or a["view_scores"].shape != (n,) or a["view_depth"].shape != (n,)
            or desc.ndim != 2 or len(desc) != n or a["view_size"].shape != (2,)
            or (level is not None and level.shape != (n,))):
        raise DataError(f"centre view arrays disagree in shape: kpts {a['view_kpts'].shape}, desc "
                        f"{desc.shape}, depth {a['view_depth'].shape}, size {a['view_size'].shape}", path)
    if desc.dtype == np.float16:
        desc = desc if compact else desc.astype(np.float32)
    elif desc.dtype == np.float32:
        desc = desc.astype(np.float16) if compact else desc
    elif desc.dtype == np.uint8:
        pass
    else:
        raise DataError(f"centre view descriptors are {desc.dtype}; expected float16 (or float32) or uint8 "
                        "(binary)", path)
    size = (int(a["view_size"][0]), int(a["view_size"][1]))
    try:
        view = RevisitView(K, a["view_kpts"], a["view_depth"], size)
    except GraphError as exc:
        raise DataError(f"centre view: {exc}", path) from exc
    return Features(a["view_kpts"], a["view_scores"], desc, size, level), view
