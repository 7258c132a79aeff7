"""Checkpointing writer of the map archive: new submaps' points once, the manifest at every commit."""
from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path

import numpy as np

from runtime.errors import DataError
from runtime.files import atomic_write_bytes
from runtime.mapping.submap import Submap
from tools.map_archive.format import (
    ARRAYS,
    FORMAT,
    MANIFEST_NAME,
    SCHEMA_VERSION,
    SUBMAP_RE,
    TEMP_RE,
    VIEW_ARRAYS,
    davio_version,
    jsonable,
    submap_filename,
)


def submap_arrays(sm: Submap, views: bool = True) -> dict[str, np.ndarray]:
    """The arrays of a submap's .npz (ARRAYS names and dtypes), and its centre view's (`view_arrays`)
    when it has one and `views`; its graph state is not among them."""
    if len(sm.frame_t_ns) > 256:
        raise ValueError(f"submap {sm.index}: {len(sm.frame_t_ns)} images; the archive stores at most 256")
    values = {"index": sm.index, "frame_t_ns": sm.frame_t_ns, "centre": sm.centre, "T_OS": sm.T_OS,
              "T_SC": sm.T_SC, "K": sm.K, "s_hat": sm.s_hat, "frame_scales": sm.frame_scales,
              "points_C": sm.points_C, "image": sm.image, "conf": sm.conf, "grey": sm.grey}
    out = {k: np.asarray(values[k]).astype(dt, order="C", copy=False) for k, dt in ARRAYS.items()}
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
    version, segment, fit) lives in the manifest, so a state change rewrites only the manifest. The
    manifest is replaced after the npz files it references, each through a temporary file and a
    rename, so the folder reloads whenever the process dies.

    A long run's manifest grows by about 1.5 kB a submap (3.5 MB after an hour), and it is rewritten at
    every commit. Re-encoding all of it each time held the model worker (and, through the GIL, the tracking
    thread) for 0.19 s per commit after an hour and 0.76 s after four (`davio bench long-run`); the writer
    therefore keeps each submap entry's and pair
    record's JSON text and re-encodes only the entries a commit changes and the pairs it adds. The text
    is the same as `json.dumps(manifest, indent=1)`.

    Args:
        folder: the archive folder (created if needed).
        header: {"rig": dict, "model": dict, "config": dict} copied into every manifest.
        overwrite: replace an archive already in `folder` (its submap files and manifest are removed);
            without it such a folder is refused with DataError.
        views: store each submap's centre view (`MappingConfig.archive_views`).
    """

    def __init__(self, folder: str | Path, header: dict, overwrite: bool = False, views: bool = True) -> None:
        self.folder = Path(folder)
        self.views = bool(views)
        self.header = {k: jsonable(header.get(k) or {}) for k in ("rig", "model", "config")}
        manifest = self.folder / MANIFEST_NAME
        if manifest.exists() and not overwrite:
            raise DataError("the folder already holds a map archive (manifest.json); choose another "
                            "output folder or overwrite it", self.folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        if overwrite:
            for p in self.folder.iterdir():
                ours = p.name == MANIFEST_NAME or SUBMAP_RE.match(p.name) or TEMP_RE.match(p.name)
                if ours and p.is_file():
                    p.unlink()
        self._entries: dict[int, dict] = {}
        self._entry_text: dict[int, str] = {}      # index -> the entry's JSON, indented as in the manifest
        self._pair_text: list[str] = []
        self._pair_objs: list[dict] = []            # the records _pair_text encodes (identity checked)
        self.map_version = 0

    @property
    def entries(self) -> list[dict]:
        """Manifest entries of every submap committed so far, by index (read only: the manifest writes the
        text encoded when the entry last went through `commit`)."""
        return [self._entries[k] for k in sorted(self._entries)]

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
        for sm in submaps:
            entry = self._entries.get(sm.index)
            if entry is None:
                entry = self._write_points(sm)
            elif entry["n_points"] != sm.n_points:
                raise ValueError(f"submap {sm.index}: points changed after they were archived "
                                 f"({entry['n_points']} -> {sm.n_points})")
            entry.update(T_MS=jsonable(np.asarray(sm.T_MS, np.float64)), lam=jsonable(float(sm.lam)),
                         version=int(sm.version), segment=int(sm.segment), fit=jsonable(dict(sm.fit)))
            self._entries[sm.index] = entry
            self._entry_text[sm.index] = _element_text(entry)
        self.map_version = int(version)
        self._encode_pairs(list(pairs))
        manifest = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "created_by": davio_version(),
                    **self.header, "map_version": self.map_version, "submaps": _SUBMAPS_SLOT,
                    "pairs": _PAIRS_SLOT, "stats": jsonable(dict(stats))}
        text = json.dumps(manifest, allow_nan=False, indent=1)
        slots = (json.dumps(_SUBMAPS_SLOT), json.dumps(_PAIRS_SLOT))
        if all(text.count(slot) == 1 for slot in slots):   # split the skeleton only, never the elements
            head, rest = text.split(slots[0])
            middle, tail = rest.split(slots[1])
            text = "".join((head, _list_text([self._entry_text[k] for k in sorted(self._entry_text)]), middle,
                            _list_text(self._pair_text), tail))
        else:   # a header or stats value holds a slot's text: encode the whole manifest
            manifest.update(submaps=self.entries, pairs=jsonable(list(pairs)))
            text = json.dumps(manifest, allow_nan=False, indent=1)
        atomic_write_bytes(self.folder / MANIFEST_NAME, text.encode())

    def _encode_pairs(self, pairs: list) -> None:
        """Bring the cached pair texts up to `pairs`: records already encoded (the same objects, in the same
        places) keep their text; from the first that differs on, records are encoded."""
        keep = 0
        for old, new in zip(self._pair_objs, pairs, strict=False):
            if old is not new:
                break
            keep += 1
        del self._pair_objs[keep:], self._pair_text[keep:]
        for rec in pairs[keep:]:
            self._pair_objs.append(rec)
            self._pair_text.append(_element_text(jsonable(rec)))

    def _write_points(self, sm: Submap) -> dict:
        arrays = submap_arrays(sm, self.views)
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        data = buf.getvalue()
        name = submap_filename(sm.index)
        atomic_write_bytes(self.folder / name, data)
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
