"""Map archive: round trip, crash mid-commit, damaged archives, PLY via open3d, `davio map` CLI.

Expectations are independent of the code under test: arrays against the submaps we wrote, exports
against a python-dict voxel average of eq. (placement) computed here.
"""
from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from runtime.errors import DataError
from runtime.mapping.submap import Submap
from tools.cli import main
from tools.map_archive import (
    MapArchiveWriter,
    check_integrity,
    fuse_archive,
    iter_submaps,
    load_submap,
    read_manifest,
    write_ply,
)

VOXEL = 0.25
HEADER = {"rig": {"camera": "pinhole"}, "model": {"name": "test"}, "config": {"voxel_m": VOXEL}}


def _rot(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _pose(rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _rot(rng), rng.normal(scale=scale, size=3)
    return T


def make_submap(index: int, seed: int, n_img: int = 3, n_pts: int = 400) -> Submap:
    rng = np.random.default_rng(seed)
    T_SC = np.stack([_pose(rng, 0.2) for _ in range(n_img)])
    T_SC[1] = np.eye(4)
    return Submap(
        index=index, frame_t_ns=np.int64(10**18) + np.arange(n_img, dtype=np.int64) * 500_000_001 + index,
        centre=1, T_OS=_pose(rng), T_SC=T_SC, K=np.array([[400.0, 0, 250], [0, 410.0, 180], [0, 0, 1]]),
        s_hat=float(np.exp(rng.normal(scale=0.1))), frame_scales=np.exp(rng.normal(scale=0.05, size=n_img)),
        points_C=rng.uniform([-1, -1, 0.5], [1, 1, 2.0], size=(n_pts, 3)).astype(np.float32),
        image=rng.integers(0, n_img, n_pts).astype(np.uint8),
        conf=rng.uniform(1, 20, n_pts).astype(np.float32), grey=rng.integers(0, 256, n_pts).astype(np.uint8),
        T_MS=_pose(rng, 0.5), lam=float(rng.normal(scale=0.1)),
        version=1, segment=0, fit={"baseline_m": 0.3, "fit_rmse_m": 0.01, "log_s_hat": float("nan")})


def brute_force_fusion(submaps: list[Submap], voxel: float) -> dict[tuple, tuple]:
    """{voxel index: (mean position, rounded mean grey, count)}: eq. (placement) point by point."""
    acc: dict[tuple, list] = {}
    for sm in submaps:
        for p_c, i, g in zip(sm.points_C.astype(np.float64), sm.image, sm.grey, strict=True):
            T_MC = sm.T_MS @ sm.T_SC[int(i)]
            p = T_MC[:3, :3] @ (np.exp(sm.lam) * p_c) + T_MC[:3, 3]
            key = tuple(int(k) for k in np.floor(p / voxel))
            a = acc.setdefault(key, [np.zeros(3), 0.0, 0])
            a[0] += p
            a[1] += float(g)
            a[2] += 1
    return {k: (s / n, int(np.clip(np.round(gs / n), 0, 255)), n) for k, (s, gs, n) in acc.items()}


def assert_fusion_equals(fused: tuple, expected: dict, voxel: float) -> None:
    pts, grey, counts = fused
    assert len(pts) == len(expected)
    for p, g, n in zip(pts, grey, counts, strict=True):
        e = expected[tuple(int(k) for k in np.floor(p / voxel))]
        np.testing.assert_allclose(p, e[0], atol=1e-9)
        assert int(g) == e[1] and int(n) == e[2]


def assert_same_submap(a: Submap, b: Submap) -> None:
    for name in ("frame_t_ns", "T_OS", "T_SC", "K", "frame_scales", "points_C", "image", "conf", "grey",
                 "T_MS"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert (a.index, a.centre, a.s_hat, a.lam, a.version, a.segment) == \
        (b.index, b.centre, b.s_hat, b.lam, b.version, b.segment)


def write_two_commits(folder: Path, close: bool = True) -> tuple[MapArchiveWriter, list[Submap]]:
    """An archive of three submaps in two commits, the second a journal line; `close`: as a finished run
    leaves it (manifest.json whole, no journal)."""
    subs = [make_submap(k, seed=k) for k in range(3)]
    w = MapArchiveWriter(folder, HEADER)
    w.commit(subs[:2], pairs=[{"a": 0, "b": 1, "ratio": 1.02}], version=1, stats={"windows": 2})
    subs[0].T_MS = _pose(np.random.default_rng(99), 0.5)
    subs[0].lam, subs[0].version = -0.05, 2
    w.commit([subs[2], subs[0]], pairs=[{"a": 0, "b": 1}, {"a": 1, "b": 2}], version=2,
             stats={"windows": 3, "rmse": float("inf")})
    if close:
        w.close()
    return w, subs


def test_round_trip_and_export_equals_brute_force(tmp_path):
    folder = tmp_path / "run" / "map"
    w, subs = write_two_commits(folder, close=False)
    during = read_manifest(folder)                   # the second commit is a journal line
    assert during["map_version"] == 2
    assert during["journal"] == {"commits": 1, "stale": 0, "incomplete_bytes": 0}
    w.close()                                        # the end of a run: manifest.json whole, no journal
    names = ["manifest.json", *(f"submap_00000{k}.npz" for k in range(3))]
    assert sorted(p.name for p in folder.iterdir()) == names
    info = json.loads((folder / "manifest.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert info == {k: v for k, v in during.items() if k not in ("journal", "journal_generation")} | {
        "journal_generation": 2}
    assert info["format"] == "davio-map" and info["schema_version"] == 3 and info["map_version"] == 2
    assert info["rig"] == HEADER["rig"] and len(info["pairs"]) == 2 and info["stats"]["rmse"] is None
    assert [e["index"] for e in info["submaps"]] == [0, 1, 2]
    assert info["submaps"][0]["fit"]["log_s_hat"] is None and info["submaps"][0]["version"] == 2
    assert info["submaps"][0]["frame_t_ns"] == [int(t) for t in subs[0].frame_t_ns]
    for p in folder.iterdir():
        assert stat.S_IMODE(p.stat().st_mode) == 0o644, p.name
    loaded = list(iter_submaps(folder))
    for a, b in zip(subs, loaded, strict=True):
        assert_same_submap(a, b)
    assert check_integrity(folder) == []
    assert_fusion_equals(fuse_archive(folder, VOXEL), brute_force_fusion(subs, VOXEL), VOXEL)


def _expected_entry(folder: Path, sm: Submap) -> dict:
    """A submap's manifest entry built from the submap and its file (not from the writer's state)."""
    import hashlib

    from tools.map_archive.format import jsonable

    name = f"submap_{sm.index:06d}.npz"
    data = (folder / name).read_bytes()
    return {"index": sm.index, "file": name, "sha256": hashlib.sha256(data).hexdigest(),
            "bytes": len(data), "n_points": sm.n_points, "frame_t_ns": [int(t) for t in sm.frame_t_ns],
            "centre": int(sm.centre), "T_MS": jsonable(np.asarray(sm.T_MS, np.float64)),
            "T_OS": jsonable(np.asarray(sm.T_OS, np.float64)), "lam": float(sm.lam),
            "scale_s_hat": float(sm.s_hat), "version": int(sm.version), "segment": int(sm.segment),
            "fit": jsonable(dict(sm.fit))}


@pytest.mark.parametrize("whole_every_commit", [False, True])
def test_manifest_equals_encoding_the_whole_manifest_after_every_commit(tmp_path, whole_every_commit):
    """Commit after commit, manifest.json and its journal read back as the whole manifest; when written
    whole (here: after every commit, or at the end), its text is what encoding the whole manifest at once
    gives (the writer re-encodes only the entries changed since, and the pairs added)."""
    from tools.map_archive.format import FORMAT, SCHEMA_VERSION, davio_version, jsonable

    folder = tmp_path / "map"
    subs = [make_submap(k, seed=20 + k) for k in range(4)]
    w = MapArchiveWriter(folder, HEADER)
    rng = np.random.default_rng(5)
    pairs: list[dict] = []
    # (submaps committed: new ones, then ones whose state moved; pair records added)
    plan = [([0, 1], 1), ([2, 0], 2), ([], 0), ([3, 1, 2], 1), ([0], 0)]
    most_lines = 0
    archived: set[int] = set()
    for version, (committed, n_pairs) in enumerate(plan, start=1):
        for k in committed:
            if k in archived:                          # already archived: its graph state moves
                subs[k].T_MS, subs[k].lam = _pose(rng, 0.3), float(rng.normal(0, 0.05))
                subs[k].version = version
        for _ in range(n_pairs):
            pairs.append({"a": len(pairs), "b": len(pairs) + 1, "kappa": float(rng.normal()),
                          "m": [float(rng.normal()), float("nan")]})
        if version == 4:
            pairs[0] = {"a": 0, "b": 9, "method": "revisit"}     # a record replaced by another object
        stats = {"windows": version, "rmse": float("inf") if version == 2 else 0.1}
        w.commit([subs[k] for k in committed], pairs, version, stats)
        archived.update(committed)
        if whole_every_commit:
            w.compact()
        entries = [_expected_entry(folder, subs[k]) for k in sorted(archived)]
        assert w.entries == entries and w.n_submaps == len(archived)
        expected = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "created_by": davio_version(),
                    "archive_id": w.archive_id,
                    **{k: jsonable(HEADER[k]) for k in ("rig", "model", "config")}, "map_version": version,
                    "journal_generation": w.generation, "submaps": entries, "pairs": jsonable(list(pairs)),
                    "stats": jsonable(stats)}
        info = read_manifest(folder)
        lines = len(_journal_lines(folder))
        assert info.pop("journal")["commits"] == lines and (lines == 0 or not whole_every_commit)
        most_lines = max(most_lines, lines)
        assert info == json.loads(json.dumps(expected, allow_nan=False))
        if whole_every_commit:
            assert (folder / "manifest.json").read_text() == json.dumps(expected, allow_nan=False, indent=1)
    # without forced writes both ways were taken: journal lines, and whole writes when it grew too long
    assert whole_every_commit or (most_lines >= 2 and w.whole_writes >= 2)
    assert [e["version"] for e in read_manifest(folder)["submaps"]] == [5, 4, 4, subs[3].version]
    w.commit([], [], 6, {})                            # the pairs list may also shrink
    assert read_manifest(folder)["pairs"] == [] and read_manifest(folder)["submaps"] == w.entries
    w.close()
    expected.update(map_version=6, journal_generation=w.generation, submaps=w.entries, pairs=[], stats={})
    assert (folder / "manifest.json").read_text() == json.dumps(expected, allow_nan=False, indent=1)
    assert not (folder / "manifest.journal").exists()


def _journal_lines(folder: Path) -> list[bytes]:
    path = folder / "manifest.journal"
    return path.read_bytes().splitlines() if path.exists() else []


def test_placeholder_text_in_any_value_cannot_corrupt_the_manifest(tmp_path):
    """The writer splices the encoded lists into the manifest at placeholders; a header, entry, pair or
    stats value holding a placeholder's text (whole, or after a quote) must come out as written."""
    from tools.map_archive.format import FORMAT, SCHEMA_VERSION, davio_version, jsonable
    from tools.map_archive.writer import _PAIRS_SLOT, _SUBMAPS_SLOT

    for where in ("header", "entry", "pair", "stats"):
        for value in (_SUBMAPS_SLOT, _PAIRS_SLOT, '"' + _PAIRS_SLOT, "x" + _SUBMAPS_SLOT):
            header = {**HEADER, "model": {"description": value if where == "header" else "m"}}
            folder = tmp_path / f"{where}{len(value)}{value[-3:-1]}"
            w = MapArchiveWriter(folder, header)
            sm = make_submap(0, seed=1)
            if where == "entry":
                sm.fit = {**sm.fit, "note": value}
            pairs = [{"a": 0, "b": 1, "note": value if where == "pair" else "p"}]
            stats = {"note": value if where == "stats" else "s"}
            w.commit([sm], pairs, 1, stats)
            text = (folder / "manifest.json").read_text()
            expected = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "created_by": davio_version(),
                        "archive_id": w.archive_id,
                        **{k: jsonable(header[k]) for k in ("rig", "model", "config")}, "map_version": 1,
                        "journal_generation": 1, "submaps": w.entries, "pairs": jsonable(pairs),
                        "stats": jsonable(stats)}
            assert text == json.dumps(expected, allow_nan=False, indent=1), (where, value)


def test_crash_mid_commit_leaves_previous_archive(tmp_path, monkeypatch):
    folder = tmp_path / "map"
    subs = [make_submap(k, seed=10 + k) for k in range(4)]
    w = MapArchiveWriter(folder, HEADER)
    w.commit(subs[:2], pairs=[], version=1, stats={})
    before = fuse_archive(folder, VOXEL)
    real_replace = os.replace

    def crashing_replace(src, dst):
        if Path(dst).name == "manifest.json":
            raise OSError("simulated crash")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", crashing_replace)
    subs[0].T_MS = np.eye(4)
    w.manifest_bytes = 0                     # this commit writes manifest.json whole, and crashes doing it
    with pytest.raises(OSError, match="simulated crash"):
        w.commit([subs[2], subs[0]], pairs=[], version=2, stats={})
    monkeypatch.undo()
    assert (folder / "submap_000002.npz").exists()
    info = read_manifest(folder)
    assert info["map_version"] == 1 and len(info["submaps"]) == 2
    after = fuse_archive(folder, VOXEL)
    for x, y in zip(before, after, strict=True):
        np.testing.assert_array_equal(x, y)
    notes = check_integrity(folder)
    assert len(notes) == 1 and notes[0].startswith("submap_000002.npz") and "orphan" in notes[0]
    assert main(["map", "info", str(folder)]) == 0  # an orphan is not an integrity problem

    # a crash while the end of the run writes the manifest whole leaves the journal, which still applies
    w = MapArchiveWriter(tmp_path / "map2", HEADER)
    w.commit(subs[:2], pairs=[], version=1, stats={})
    subs[1].T_MS = np.diag([1.0, 1.0, 1.0, 1.0])
    subs[1].T_MS[:3, 3] = [7.0, 8.0, 9.0]
    w.commit([subs[3], subs[1]], pairs=[{"a": 1, "b": 3}], version=2, stats={"n": 2})
    assert len(_journal_lines(w.folder)) == 1
    monkeypatch.setattr(os, "replace", crashing_replace)
    with pytest.raises(OSError, match="simulated crash"):
        w.close()
    monkeypatch.undo()
    info = read_manifest(w.folder)
    assert info["map_version"] == 2 and [e["index"] for e in info["submaps"]] == [0, 1, 3]
    assert info["submaps"][1]["T_MS"][0][3] == 7.0 and info["pairs"] == [{"a": 1, "b": 3}]
    assert check_integrity(w.folder) == []


def _expected_submaps(folder: Path, subs: list[Submap]) -> list[dict]:
    """The manifest's submap entries for the archived `subs`, by index, as JSON reads them back."""
    return json.loads(json.dumps([_expected_entry(folder, sm) for sm in sorted(subs, key=lambda s: s.index)]))


def _commit_plan(folder: Path, n_commits: int) -> tuple[MapArchiveWriter, list[dict], list[Submap]]:
    """A writer's archive after n_commits (the first one written whole, the others journal lines while
    the journal stays smaller than manifest.json); after each commit what the manifest must read as:
    map_version, the submap entries, the pairs and the stats, from the writer's own arguments and the
    submaps (not from the writer's state); and the archived submaps."""
    from tools.map_archive.format import jsonable

    rng = np.random.default_rng(7)
    subs = [make_submap(k, seed=40 + k, n_pts=30) for k in range(n_commits + 8)]
    w = MapArchiveWriter(folder, HEADER)
    pairs: list[dict] = []
    states = []
    w.commit(subs[:8], pairs, 1, {"windows": 1})
    for version in range(2, n_commits + 1):
        moved = [subs[int(k)] for k in rng.choice(version + 6, 2, replace=False)]
        for sm in moved:
            sm.T_MS = _pose(rng, 0.3)
            sm.lam, sm.version = float(rng.normal(0, 0.05)), version
        pairs.append({"a": version, "b": version + 1, "kappa": float(rng.normal())})
        w.commit([subs[version + 6], *moved], pairs, version, {"windows": version})
        states.append({"map_version": version, "submaps": _expected_submaps(folder, subs[:version + 7]),
                       "pairs": jsonable(list(pairs)), "stats": {"windows": version}})
    return w, states, subs[:n_commits + 7]


def test_killed_anywhere_in_a_journal_line_reloads_the_commits_before_it(tmp_path, capsys):
    """A run killed while appending a commit's line leaves a line without its newline: the archive reads as
    the commit before, whatever the cut; each complete line brings the next commit."""
    w, states, _ = _commit_plan(tmp_path / "map", 6)
    assert w.whole_writes == 1 and len(_journal_lines(w.folder)) == 5     # all five after the first
    journal = (w.folder / "manifest.journal").read_bytes()
    ends = [i + 1 for i, b in enumerate(journal) if b == ord("\n")]
    cuts = sorted({*range(0, len(journal) + 1, 97), *ends, *(e - 1 for e in ends),
                   *(e + 1 for e in ends[:-1])})
    for cut in cuts:
        (w.folder / "manifest.journal").write_bytes(journal[:cut])
        info = read_manifest(w.folder)
        done = sum(e <= cut for e in ends)
        want = states[done - 1] if done else {"map_version": 1}
        assert info["journal"] == {"commits": done, "stale": 0,
                                   "incomplete_bytes": cut - (ends[done - 1] if done else 0)}, cut
        assert {k: info[k] for k in want} == want, cut
    capsys.readouterr()
    assert main(["map", "info", str(w.folder)]) == 0
    assert (f"journal      {len(ends)} commit(s) since manifest.json was last written whole"
            in capsys.readouterr().out)


def test_a_journal_from_before_the_last_whole_write_is_skipped(tmp_path):
    """A kill between writing manifest.json whole and removing the journal leaves the old journal beside the
    new manifest: its lines carry the older generation and are already in the manifest."""
    w, states, _ = _commit_plan(tmp_path / "map", 4)
    old = (w.folder / "manifest.journal").read_bytes()
    w.close()
    (w.folder / "manifest.journal").write_bytes(old)
    info = read_manifest(w.folder)
    assert info["journal"] == {"commits": 0, "stale": 3, "incomplete_bytes": 0}
    assert {k: info[k] for k in states[-1]} == states[-1]


def test_the_writer_never_appends_after_bytes_it_did_not_write(tmp_path):
    """Bytes appended to the journal by someone else (or a write cut short) would join the next line: the
    writer sees the journal's length differ and writes the manifest whole instead."""
    w, states, _ = _commit_plan(tmp_path / "map", 3)
    with open(w.folder / "manifest.journal", "ab") as fh:
        fh.write(b'{"generation": 1, "map_ver')
    sm = make_submap(50, seed=50, n_pts=30)
    w.commit([sm], [], 4, {"windows": 4})
    assert not (w.folder / "manifest.journal").exists() and w.generation == 2
    info = read_manifest(w.folder)
    assert info["map_version"] == 4 and info["submaps"][-1]["index"] == 50 and info["pairs"] == []


def test_a_failed_commit_is_never_built_upon(tmp_path, monkeypatch):
    """A commit that fails after changing the writer's state (its line not written, the manifest's whole
    write failing too; or a submap whose points changed) leaves the disk behind: the next commit, or close,
    writes the manifest whole, so that the archive reads as the writer's state and never as a line that
    assumes the lost one (a pair kept that is not there, a new submap's entry missing, a wrong state)."""
    from tools.map_archive.format import jsonable

    def on_disk(w: MapArchiveWriter) -> tuple:
        info = read_manifest(w.folder)
        return info["map_version"], info["submaps"], info["pairs"]

    def expected(w: MapArchiveWriter, version: int, submaps: list[Submap], pairs: list) -> tuple:
        return version, _expected_submaps(w.folder, submaps), jsonable(list(pairs))

    real_replace = os.replace

    def failing_replace(src, dst):
        if Path(dst).name == "manifest.json":
            raise OSError("disk full")
        return real_replace(src, dst)

    for then_close in (False, True):
        w, _, archived = _commit_plan(tmp_path / f"map{then_close}", 3)
        pairs = [{"a": 0, "b": 1}]
        subs = [make_submap(k, seed=60 + k, n_pts=30) for k in (20, 21)]
        monkeypatch.setattr(w, "_append", lambda data: False)
        monkeypatch.setattr(os, "replace", failing_replace)
        with pytest.raises(OSError, match="disk full"):
            w.commit([subs[0]], pairs, 4, {"windows": 4})       # a new submap and a pair, lost
        monkeypatch.undo()
        assert on_disk(w)[0] == 3
        if then_close:
            w.close()
            assert on_disk(w) == expected(w, 4, [*archived, subs[0]], pairs)
        else:
            subs[0].T_MS = np.eye(4)
            subs[0].version = 5
            pairs = pairs + [{"a": 1, "b": 2}]
            w.commit([subs[0], subs[1]], pairs, 5, {"windows": 5})
            assert on_disk(w) == expected(w, 5, [*archived, *subs], pairs)
        assert not (w.folder / "manifest.journal").exists()

    w, states, archived = _commit_plan(tmp_path / "points", 3)
    moved = make_submap(2, seed=1, n_pts=31)                   # submap 2 is archived with 30 points
    new = make_submap(30, seed=30, n_pts=30)
    with pytest.raises(ValueError, match="points changed"):
        w.commit([new, moved], [], 4, {})
    w.close()                                                  # submap 30 archived, 2 as it was
    assert on_disk(w) == expected(w, 3, [*archived, new], states[-1]["pairs"])


def test_a_reader_that_loses_the_journal_to_a_whole_write_reads_again(tmp_path, monkeypatch):
    """The writer may write manifest.json whole and remove the journal between the reader's look at the
    journal and its read: the reader reads both again instead of failing."""
    w, states, _ = _commit_plan(tmp_path / "map", 3)
    journal = w.folder / "manifest.journal"
    real = Path.read_bytes
    calls = {"n": 0}

    def racing_read_bytes(self):
        if self == journal and calls["n"] == 0:
            calls["n"] += 1
            w.close()                                          # the whole write lands now
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", racing_read_bytes)
    info = read_manifest(w.folder)
    assert calls["n"] == 1 and info["journal"]["commits"] == 0
    assert {k: info[k] for k in states[-1]} == states[-1]


@pytest.mark.parametrize("edit, message", [
    (lambda lines: [lines[0], b"{not json", *lines[1:]], r"line 2 is not valid JSON"),
    (lambda lines: [lines[0], b"[1, 2]", *lines[1:]], r"line 2 is not a JSON object"),
    (lambda lines: [lines[0].replace(b'"pairs_keep"', b'"pairs_kept"'), *lines[1:]],
     r"line 1: pairs_keep is None, expected a non-negative integer"),
    (lambda lines: [lines[0].replace(b'"pairs_keep":0', b'"pairs_keep":9'), *lines[1:]],
     r"line 1 keeps 9 pair records of 0"),
    (lambda lines: [lines[0].replace(b'"file":', b'"fil":'), *lines[1:]], r"line 1: new submap 8 lacks file"),
    (lambda lines: [lines[0].replace(b'"generation":1', b'"generation":2'), *lines[1:]],
     r"changed 5 times while it was read: its lines are of a later generation than manifest.json's \(1\)\. "
     r"A run writing it: try again\. Otherwise manifest.json is an older copy"),
])
def test_a_damaged_journal_is_named_with_its_line(tmp_path, edit, message):
    w, _, _ = _commit_plan(tmp_path / "map", 3)
    path = w.folder / "manifest.journal"
    assert b'"pairs_keep":0' in path.read_bytes().splitlines()[0]
    path.write_bytes(b"\n".join(edit(path.read_bytes().splitlines())) + b"\n")
    with pytest.raises(DataError, match=r"manifest\.journal.*" + message):
        read_manifest(w.folder)


def test_manifest_entries_that_repeat_an_index_or_disagree_with_their_file_are_named(tmp_path):
    """A manifest entry repeated (same index or file), a point count other than its file's, and a point
    whose image index is past the submap's images (a faulty writer; checksums match) are DataErrors."""
    folder = tmp_path / "map"
    write_two_commits(folder)
    manifest = folder / "manifest.json"
    info = json.loads(manifest.read_text())
    manifest.write_text(json.dumps({**info, "submaps": [*info["submaps"], info["submaps"][0]]}))
    with pytest.raises(DataError, match=r"submaps\[3\] and submaps\[0\] have the same index 0"):
        read_manifest(folder)
    bad = [dict(e) for e in info["submaps"]]
    bad[1]["n_points"] = 10**30
    manifest.write_text(json.dumps({**info, "submaps": bad}))
    with pytest.raises(DataError, match=r"submap_000001\.npz.*holds 400 points, the manifest says 10+"):
        load_submap(folder, read_manifest(folder)["submaps"][1])
    manifest.write_text(json.dumps(info))
    path = folder / "submap_000002.npz"
    with np.load(path) as npz:
        arrays = dict(npz)
    np.savez_compressed(path, **{**arrays, "image": np.full_like(arrays["image"], 9)})
    with pytest.raises(DataError, match=r"submap_000002\.npz.*image index is 9, the submap has 3 images"):
        load_submap(folder, read_manifest(folder)["submaps"][2])
    np.savez_compressed(path, **{**arrays, "T_SC": np.float64(1.0)})
    with pytest.raises(DataError, match=r"submap_000002\.npz.*inconsistent submap arrays: T_SC \(\)"):
        load_submap(folder, read_manifest(folder)["submaps"][2])


def test_an_export_with_nothing_to_write_is_refused_and_keeps_the_old_file(tmp_path, capsys):
    folder = tmp_path / "run" / "map"
    write_two_commits(folder)
    out = tmp_path / "run" / "map.ply"
    assert main(["map", "export", str(tmp_path / "run")]) == 0
    before = out.read_bytes()
    assert main(["map", "export", str(tmp_path / "run"), "--min-points", "100000"]) == 1
    assert "nothing to export: none of the" in capsys.readouterr().err and out.read_bytes() == before
    for p in folder.glob("*.npz"):
        p.unlink()
    capsys.readouterr()
    assert main(["map", "export", str(tmp_path / "run"), "--skip-damaged"]) == 1
    assert "nothing to export: no submap could be fused (3 damaged submap file(s) left out" in \
        capsys.readouterr().err
    assert out.read_bytes() == before
    assert main(["map", "view", str(tmp_path / "run"), "--skip-damaged"]) == 1
    assert "nothing to draw" in capsys.readouterr().err


def _ray_submap(index: int, seed: int, stride: int = 4) -> Submap:
    """A submap whose points are float32 depths on a pixel grid of its K, as the mapper keeps them."""
    sm = make_submap(index, seed)
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[2:360:stride, 2:500:stride]
    image = rng.integers(0, 3, u.size)
    depth = rng.uniform(0.3, 12.0, u.size).astype(np.float32)
    K = sm.K
    x = (u.ravel() - K[0, 2]) / K[0, 0] * depth.astype(np.float64)
    y = (v.ravel() - K[1, 2]) / K[1, 1] * depth.astype(np.float64)
    sm.points_C = np.stack([x, y, depth], axis=1).astype(np.float32)
    sm.image = image.astype(np.uint8)
    sm.conf = rng.uniform(1, 20, u.size).astype(np.float32)
    sm.grey = rng.integers(0, 256, u.size).astype(np.uint8)
    return sm


def test_points_on_pixel_rays_are_stored_as_depths_and_pixels_and_read_back_bit_for_bit(tmp_path):
    """Schema 3: the mapper's points (float32 depths on pixels of K) are stored as depth and pixel, a
    third of the bytes of x, y, z; a submap with one point off its ray keeps x, y, z. Both read back
    equal to what was written, and fuse as the points written."""
    on_ray = _ray_submap(0, seed=3)
    off_ray = _ray_submap(1, seed=3)
    off_ray.index = 1
    off_ray.points_C = off_ray.points_C.copy()
    off_ray.points_C[7, 0] += 0.01
    folder = tmp_path / "map"
    w = MapArchiveWriter(folder, HEADER)
    w.commit([on_ray, off_ray], pairs=[], version=1, stats={})
    w.close()
    with np.load(folder / "submap_000000.npz") as a, np.load(folder / "submap_000001.npz") as b:
        assert "points_C" not in a.files and a["depth"].dtype == np.float32
        np.testing.assert_array_equal(a["depth"], on_ray.points_C[:, 2])
        assert a["pixel_u"].dtype == a["pixel_v"].dtype == np.uint16
        assert a["pixel_u"].shape == a["pixel_v"].shape == (on_ray.n_points,)
        assert not {"depth", "pixel_u", "pixel_v"} & set(b.files)
        np.testing.assert_array_equal(b["points_C"], off_ray.points_C)
    sizes = [(folder / f"submap_00000{k}.npz").stat().st_size for k in range(2)]
    assert sizes[0] < 0.7 * sizes[1]
    for a, b in zip([on_ray, off_ray], iter_submaps(folder), strict=True):
        assert_same_submap(a, b)
    assert_fusion_equals(fuse_archive(folder, VOXEL), brute_force_fusion([on_ray, off_ray], VOXEL), VOXEL)


def test_a_submap_file_without_points_or_with_mismatched_rays_is_named(tmp_path):
    folder = tmp_path / "map"
    w = MapArchiveWriter(folder, HEADER)
    w.commit([_ray_submap(0, seed=4)], pairs=[], version=1, stats={})
    w.close()
    path = folder / "submap_000000.npz"
    entry = read_manifest(folder)["submaps"][0]
    with np.load(path) as npz:
        arrays = dict(npz)
    np.savez(path, **{k: v for k, v in arrays.items() if k != "pixel_v"})
    with pytest.raises(DataError, match=r"submap_000000\.npz.*holds no points: neither array 'points_C' nor "
                                        r"'depth', 'pixel_u', 'pixel_v'"):
        load_submap(folder, entry)
    np.savez(path, **{**arrays, "pixel_u": arrays["pixel_u"][:-1]})
    with pytest.raises(DataError, match=r"submap_000000\.npz.*inconsistent submap arrays: depth"):
        load_submap(folder, entry)


def test_schema_1_archives_are_read_without_a_journal(tmp_path):
    """An archive written before the journal (schema 1: no journal_generation) reads as its manifest.json,
    even beside a journal file, which only schema 2 defines."""
    w, states, _ = _commit_plan(tmp_path / "map", 3)
    w.close()
    manifest = w.folder / "manifest.json"
    info = json.loads(manifest.read_text())
    del info["journal_generation"]
    manifest.write_text(json.dumps({**info, "schema_version": 1}))
    (w.folder / "manifest.journal").write_bytes(b"not even json\n")
    got = read_manifest(w.folder)
    assert got["schema_version"] == 1 and got["journal"]["commits"] == 0
    assert {k: got[k] for k in states[-1]} == states[-1]
    manifest.write_text(json.dumps({**info, "schema_version": 2}))
    with pytest.raises(DataError, match="journal_generation is None"):
        read_manifest(w.folder)


def test_damaged_archives_are_named(tmp_path, capsys):
    folder = tmp_path / "map"
    write_two_commits(folder)
    target = folder / "submap_000001.npz"
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0xFF
    target.write_bytes(bytes(data))
    problems = check_integrity(folder)
    assert len(problems) == 1 and "submap_000001.npz" in problems[0] and "sha256" in problems[0]
    assert main(["map", "info", str(folder)]) == 1
    assert "submap_000001.npz" in capsys.readouterr().out

    trunc = folder / "submap_000002.npz"
    trunc.write_bytes(trunc.read_bytes()[: trunc.stat().st_size // 2])
    entry = read_manifest(folder)["submaps"][2]
    with pytest.raises(DataError, match="submap_000002.npz"):
        load_submap(folder, entry)
    assert any(p.startswith("submap_000002.npz") for p in check_integrity(folder))

    manifest = folder / "manifest.json"
    manifest.write_text("{not json")
    with pytest.raises(DataError, match="manifest.json.*not valid JSON"):
        read_manifest(folder)
    manifest.write_text(json.dumps({"schema_version": 1, "submaps": []}))
    with pytest.raises(DataError, match="foreign archive"):
        read_manifest(folder)
    manifest.write_text(json.dumps({"format": "davio-map", "schema_version": 7, "submaps": []}))
    with pytest.raises(DataError, match="newer davio.*needs schema 7 support"):
        read_manifest(folder)
    manifest.write_text(json.dumps({"format": "davio-map", "schema_version": 0, "submaps": []}))
    with pytest.raises(DataError, match="schema 0"):
        read_manifest(folder)
    with pytest.raises(DataError, match="not found"):
        read_manifest(tmp_path / "nowhere")


def test_writer_refuses_existing_archive_unless_overwrite(tmp_path):
    folder = tmp_path / "map"
    write_two_commits(folder)
    with pytest.raises(DataError, match=str(folder)):
        MapArchiveWriter(folder, HEADER)
    w = MapArchiveWriter(folder, HEADER, overwrite=True)
    assert not any(folder.iterdir())
    w.commit([make_submap(5, seed=5)], pairs=[], version=1, stats={})
    assert [e["index"] for e in read_manifest(folder)["submaps"]] == [5]


def test_ply_opens_in_open3d(tmp_path):
    import open3d as o3d  # a declared dependency (its Linux wheel needs libusb-1.0: README, .ci/run)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 5, size=(257, 3))
    grey = rng.integers(0, 256, 257).astype(np.uint8)
    path = tmp_path / "cloud.ply"
    write_ply(path, pts, grey)
    pcd = o3d.io.read_point_cloud(str(path))
    assert len(pcd.points) == 257
    np.testing.assert_allclose(np.asarray(pcd.points), pts.astype(np.float32), rtol=0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(pcd.colors), np.repeat(grey[:, None] / 255.0, 3, axis=1), atol=1e-6)


def test_cli_info_export_view(tmp_path, capsys):
    run = tmp_path / "run"
    _, subs = write_two_commits(run / "map")
    assert main(["map", "info", str(run), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["submaps"] == 3 and info["points"] == sum(s.n_points for s in subs)
    assert info["map_version"] == 2 and info["pairs"] == 2 and info["problems"] == []
    all_pts = np.concatenate([s.points_M() for s in subs])
    np.testing.assert_allclose(info["extent"]["min"], all_pts.min(axis=0))
    np.testing.assert_allclose(info["extent"]["max"], all_pts.max(axis=0))
    assert main(["map", "info", str(run / "map")]) == 0
    assert "integrity    ok" in capsys.readouterr().out

    assert main(["map", "export", str(run), "--voxel", str(VOXEL)]) == 0
    from tools.evaluation.ply import read_ply_vertices

    exported = read_ply_vertices(run / "map.ply")
    expected = brute_force_fusion(subs, VOXEL)
    assert len(exported) == len(expected)
    expected_x = np.sort([v[0][0] for v in expected.values()])
    np.testing.assert_allclose(np.sort(exported[:, 0]), expected_x, atol=1e-5)

    capsys.readouterr()
    thin = tmp_path / "thin.ply"
    assert main(["map", "export", str(run), "--voxel", str(VOXEL), "--min-points", "2",
                 "--out", str(thin)]) == 0
    supported = {k: v for k, v in expected.items() if v[2] >= 2}
    assert 0 < len(supported) < len(expected)               # the fixture has both kinds of voxel
    assert f"({len(expected) - len(supported)} of {len(expected)} with fewer" in capsys.readouterr().out
    np.testing.assert_allclose(np.sort(read_ply_vertices(thin)[:, 0]),
                               np.sort([v[0][0] for v in supported.values()]), atol=1e-5)
    with pytest.raises(SystemExit) as refused:                  # the command line refuses it, named
        main(["map", "export", str(run), "--min-points", "0"])
    assert refused.value.code == 2 and "argument --min-points: must be >= 1" in capsys.readouterr().err

    out = tmp_path / "pic.png"
    assert main(["map", "view", str(run), "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(SystemExit):
        main(["map", "export"])
    assert main(["map", "info", str(tmp_path / "missing")]) == 1
    assert "not found" in capsys.readouterr().err
