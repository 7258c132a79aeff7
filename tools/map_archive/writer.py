"""Checkpointing writer of the map archive: new submaps' points once, a journal line at every commit."""
from __future__ import annotations

import hashlib
import io
import json
import os
import threading
import uuid
from pathlib import Path

import numpy as np

from runtime.errors import DataError
from runtime.files import FILE_MODE, atomic_write_bytes
from runtime.mapping.submap import Submap
from tools.map_archive.format import (
    ARRAYS,
    FORMAT,
    JOURNAL_NAME,
    MANIFEST_NAME,
    POINTS_ARRAY,
    SCHEMA_VERSION,
    SUBMAP_RE,
    TEMP_RE,
    VIEW_ARRAYS,
    davio_version,
    jsonable,
    submap_filename,
)
from tools.map_archive.point_rays import encode_rays


def submap_arrays(sm: Submap, views: bool = True) -> dict[str, np.ndarray]:
    """The arrays of a submap's .npz (ARRAYS names and dtypes; the points as RAY_ARRAYS where that is
    exact, else POINTS_ARRAY), and its centre view's (`view_arrays`) when it has one and `views`; its
    graph state is not among them."""
    if len(sm.frame_t_ns) > 256:
        raise ValueError(f"submap {sm.index}: {len(sm.frame_t_ns)} images; the archive stores at most 256")
    values = {"index": sm.index, "frame_t_ns": sm.frame_t_ns, "centre": sm.centre, "T_OS": sm.T_OS,
              "T_SC": sm.T_SC, "K": sm.K, "s_hat": sm.s_hat, "frame_scales": sm.frame_scales,
              "image": sm.image, "conf": sm.conf, "grey": sm.grey}
    out = {k: np.asarray(values[k]).astype(dt, order="C", copy=False) for k, dt in ARRAYS.items()}
    name, dtype = POINTS_ARRAY
    points = np.asarray(sm.points_C).astype(dtype, order="C", copy=False)
    rays = encode_rays(points, out["K"])
    if rays is None:
        out[name] = points
    else:
        out.update(rays)
    if views and sm.view is not None:
        out.update(view_arrays(*sm.view))
    return out


def view_arrays(features, view) -> dict[str, np.ndarray]:
    """The centre-view arrays of a submap's .npz (`VIEW_ARRAYS`, `view_desc`, `view_level`) from its
    matcher features and RevisitView (the same keypoints)."""
    kpts = np.asarray(features.kpts, np.float32)
    if len(kpts) != len(view.kpts):
        raise ValueError(f"centre view: {len(kpts)} feature keypoints but {len(view.kpts)} view keypoints")
    values = {"view_kpts": kpts, "view_scores": features.scores, "view_depth": view.depth_at_kpts,
              "view_size": view.image_size}
    out = {k: np.asarray(values[k]).astype(dt, order="C", copy=False) for k, dt in VIEW_ARRAYS.items()}
    desc = np.asarray(features.desc)
    binary = not np.issubdtype(desc.dtype, np.floating)
    out["view_desc"] = desc.astype(np.uint8 if binary else np.float16, order="C")
    if features.level is not None:
        out["view_level"] = np.asarray(features.level, np.int8)
    return out


class MapArchiveWriter:
    """Writes a run's `map/` folder, one checkpoint per map commit.

    Submap points are written once (one npz per submap, never rewritten); graph state (T_MS, lambda,
    version, segment, fit) lives in the manifest. A commit appends one line to manifest.journal: the new
    submaps' entries, the state of the submaps it moved, the pair records it added and the mapper's
    counters. When the journal has grown to the size of manifest.json, manifest.json is written whole
    (through a temporary file and a rename) with the next journal generation, and the journal is removed;
    `close` does the same at the end of a run, so a finished archive is manifest.json alone.

    Why a journal: manifest.json grows by about 1.5 kB a submap (3.5 MB after an hour, 14 MB after four),
    and writing it whole at every commit (a submap every 1.5 s) wrote 9 MB/s to the robot's disk after four
    hours, nine times what the submaps' points need (`davio bench long-run`). With the journal a commit
    writes what it changed, and the rewrites add as much again (each one follows a journal as large).

    A process killed at any moment leaves an archive that reloads (`read_manifest`): npz files are written
    before the line that names them, a line cut short by the kill is ignored (the commit in flight is
    lost), and a journal left from before the last whole write carries the older generation and is skipped.
    A commit that fails (an OSError, a ValueError) leaves the disk behind the writer's state: the next
    commit, or `close`, writes the manifest whole instead of a line that would build on the lost one.
    Nothing is fsync'ed (as every DAVIO output): a killed process is covered, a power cut may lose the
    last commits the operating system had not written. Commits and `close` are serialised by a lock.
    The whole manifest's text is `json.dumps(manifest, indent=1)`; the writer keeps each submap entry's and
    pair record's text, encoded when committed, so that a whole write only joins them (encoding every
    entry moved since the last one at that moment held the GIL for 0.16 s after an hour).

    Args:
        folder: the archive folder (created if needed).
        header: {"rig": dict, "model": dict, "config": dict} copied into every manifest.
        overwrite: replace an archive already in `folder` (its submap files, manifest and journal are
            removed); without it such a folder is refused with DataError.
        views: store each submap's centre view (`MappingConfig.archive_views`).
    """

    def __init__(self, folder: str | Path, header: dict, overwrite: bool = False, views: bool = True) -> None:
        self.folder = Path(folder)
        self.views = bool(views)
        self.header = {k: jsonable(header.get(k) or {}) for k in ("rig", "model", "config")}
        self.archive_id = uuid.uuid4().hex
        """Names this archive for good (alignment.json records the ids of the maps it relates: a map
        replaced at the same path is then told from the one aligned to)."""
        manifest = self.folder / MANIFEST_NAME
        if manifest.exists() and not overwrite:
            raise DataError("the folder already holds a map archive (manifest.json); choose another "
                            "output folder or overwrite it", self.folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        if overwrite:
            for p in self.folder.iterdir():
                ours = (p.name in (MANIFEST_NAME, JOURNAL_NAME) or SUBMAP_RE.match(p.name)
                        or TEMP_RE.match(p.name))
                if ours and p.is_file():
                    p.unlink()
        # index -> the entry's JSON, indented as in the manifest: the only copy of an entry kept (a dict of
        # it took 2.9 kB more a submap, 28 MB after four hours); a moved submap's entry is decoded again
        self._entry_text: dict[int, str] = {}
        self._n_points: dict[int, int] = {}        # index -> points archived (they must not change)
        self._pair_objs: list = []                 # the records last committed (identity checked)
        self._pair_text: list[str] = []            # ... encoded for the manifest (their only copy kept)
        self._stats: dict = {}
        self.map_version = 0
        self.generation = 0
        """Journal generation of the last whole manifest.json (0: none written yet)."""
        self.manifest_bytes = 0
        self.journal_bytes = 0
        self.bytes_written = 0
        """Manifest and journal bytes written so far (submap files not counted)."""
        self.points_bytes = 0
        """Bytes of the submap files written so far."""
        self.whole_writes = 0
        """Whole writes of manifest.json so far."""
        self._behind = False      # a commit failed after it changed the state: the disk lags it
        self._lock = threading.Lock()

    @property
    def entries(self) -> list[dict]:
        """Manifest entries of every submap committed so far, by index (decoded anew at each call)."""
        return [json.loads(self._entry_text[k]) for k in sorted(self._entry_text)]

    @property
    def n_submaps(self) -> int:
        """How many submaps were committed so far."""
        return len(self._entry_text)

    @property
    def journal_path(self) -> Path:
        return self.folder / JOURNAL_NAME

    def commit(self, submaps: list[Submap], pairs: list[dict], version: int, stats: dict) -> None:
        """Checkpoint one map commit.

        Args:
            submaps: new submaps and submaps whose graph state changed (others keep their entries).
                A submap's points must not change once written.
            pairs: the graph's pair records (written as given, non-finite floats as null); a record
                already written is not encoded again while the same object stays at its place.
            version: the map version of this commit.
            stats: counters and figures of the mapper (written as given).
        """
        with self._lock:
            self._commit(submaps, pairs, version, stats)

    def _commit(self, submaps: list[Submap], pairs: list[dict], version: int, stats: dict) -> None:
        behind, self._behind = self._behind, True      # cleared once this commit reaches the disk
        records = []
        for sm in submaps:
            text = self._entry_text.get(sm.index)
            new = text is None
            if new:
                entry = self._write_points(sm)
                self._n_points[sm.index] = entry["n_points"]
            elif self._n_points[sm.index] != sm.n_points:
                raise ValueError(f"submap {sm.index}: points changed after they were archived "
                                 f"({self._n_points[sm.index]} -> {sm.n_points})")
            else:
                entry = json.loads(text)
            state = {"T_MS": jsonable(np.asarray(sm.T_MS, np.float64)), "lam": jsonable(float(sm.lam)),
                     "version": int(sm.version), "segment": int(sm.segment), "fit": jsonable(dict(sm.fit))}
            entry.update(state)
            self._entry_text[sm.index] = _element_text(entry)   # now, so a whole write only joins texts
            records.append(entry if new else {"index": int(sm.index), **state})
        keep, added = self._take_pairs(list(pairs))
        self.map_version = int(version)
        self._stats = jsonable(dict(stats))
        line = json.dumps({"generation": self.generation, "map_version": self.map_version, "submaps": records,
                           "pairs_keep": keep, "pairs": added, "stats": self._stats},
                          allow_nan=False, separators=(",", ":")) + "\n"
        data = line.encode()
        full = self.journal_bytes + len(data) > self.manifest_bytes
        if behind or self.generation == 0 or full or not self._append(data):
            self._compact()
        self._behind = False

    def close(self) -> None:
        """Write manifest.json whole and remove the journal (the end of a run); a no-op when the journal is
        empty and no commit failed. The archive stays valid if this fails (the journal still brings the
        manifest up to date)."""
        with self._lock:
            if self._behind or (self.generation and (self.journal_bytes or self.journal_path.exists())):
                self._compact()
                self._behind = False

    def compact(self) -> None:
        """Write manifest.json whole, with the next journal generation, then remove the journal."""
        with self._lock:
            self._compact()

    def _compact(self) -> None:
        generation = self.generation + 1
        data = self._manifest_text(generation).encode()
        atomic_write_bytes(self.folder / MANIFEST_NAME, data)
        self.whole_writes += 1
        self.generation, self.manifest_bytes = generation, len(data)
        self.bytes_written += len(data)
        self.journal_path.unlink(missing_ok=True)
        self.journal_bytes = 0

    def _append(self, data: bytes) -> bool:
        """Append one commit's line to the journal (unbuffered); False (nothing appended) when the file is not
        what this writer wrote or the write failed, in which case the caller writes the manifest whole. A
        write cut short is truncated away; where even that fails, the file's length no longer matches and no
        later line is appended to it."""
        try:
            fd = os.open(self.journal_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, FILE_MODE)
        except OSError:
            return False
        try:
            if os.fstat(fd).st_size != self.journal_bytes:
                return False
            view = memoryview(data)
            try:
                while view:
                    view = view[os.write(fd, view):]
            except OSError:
                try:
                    os.ftruncate(fd, self.journal_bytes)   # never leave half a line before the next one
                except OSError:
                    pass
                return False
        finally:
            os.close(fd)
        self.journal_bytes += len(data)
        self.bytes_written += len(data)
        return True

    def _take_pairs(self, pairs: list) -> tuple[int, list]:
        """Bring the pair records up to `pairs`; returns how many of the previous ones stay (the same
        objects at the same places) and the others, replaced or added, as strict-JSON data."""
        keep = 0
        for old, new in zip(self._pair_objs, pairs, strict=False):
            if old is not new:
                break
            keep += 1
        del self._pair_objs[keep:], self._pair_text[keep:]
        added = [jsonable(rec) for rec in pairs[keep:]]
        self._pair_objs.extend(pairs[keep:])
        self._pair_text.extend(_element_text(rec) for rec in added)
        return keep, added

    def _manifest_text(self, generation: int) -> str:
        """The whole manifest as `json.dumps(manifest, indent=1)` writes it, from the cached element texts."""
        manifest = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "created_by": davio_version(),
                    "archive_id": self.archive_id, **self.header, "map_version": self.map_version,
                    "journal_generation": generation,
                    "submaps": _SUBMAPS_SLOT, "pairs": _PAIRS_SLOT, "stats": self._stats}
        text = json.dumps(manifest, allow_nan=False, indent=1)
        slots = (json.dumps(_SUBMAPS_SLOT), json.dumps(_PAIRS_SLOT))
        if all(text.count(slot) == 1 for slot in slots):   # split the skeleton only, never the elements
            head, rest = text.split(slots[0])
            middle, tail = rest.split(slots[1])
            return "".join((head, _list_text([self._entry_text[k] for k in sorted(self._entry_text)]), middle,
                            _list_text(self._pair_text), tail))
        # a value holds a slot's text: the lists decoded again and the whole manifest encoded at once
        manifest.update(submaps=self.entries, pairs=[json.loads(text) for text in self._pair_text])
        return json.dumps(manifest, allow_nan=False, indent=1)

    def _write_points(self, sm: Submap) -> dict:
        arrays = submap_arrays(sm, self.views)
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        data = buf.getvalue()
        name = submap_filename(sm.index)
        atomic_write_bytes(self.folder / name, data)
        self.points_bytes += len(data)
        return {"index": int(sm.index), "file": name, "sha256": hashlib.sha256(data).hexdigest(),
                "bytes": len(data), "n_points": sm.n_points, "frame_t_ns": [int(t) for t in sm.frame_t_ns],
                "centre": int(sm.centre), "T_MS": None, "T_OS": jsonable(arrays["T_OS"]), "lam": 0.0,
                "scale_s_hat": jsonable(float(sm.s_hat)), "version": 0, "segment": 0, "fit": {}}


_SUBMAPS_SLOT = "\x00davio:submaps\x00"
_PAIRS_SLOT = "\x00davio:pairs\x00"
"""Placeholders for the two long lists in the encoded manifest; a commit whose other values contain either
one's encoded text (found by counting) is encoded whole instead."""


def _element_text(value: object) -> str:
    """`value` encoded as an element of a list one level inside the manifest (json.dumps, indent=1)."""
    return "\n".join("  " + line for line in json.dumps(value, allow_nan=False, indent=1).split("\n"))


def _list_text(elements: list[str]) -> str:
    """A top-level list value of the manifest from its encoded elements, as json.dumps(indent=1) writes it."""
    return "[\n" + ",\n".join(elements) + "\n ]" if elements else "[]"
