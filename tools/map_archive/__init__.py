"""The on-disk map archive (DESIGN §4 "On-disk outputs of a run"): one compressed .npz per submap
with its retained points, and a manifest.json with the graph state of every submap.

Layout of a run's `map/` folder::

    manifest.json          format, schema, rig/model/config, map version, per-submap state, pairs, stats
    manifest.journal       while a run maps: the commits since manifest.json was last written whole
    submap_000000.npz      retained points of submap 0 (written once, never rewritten)
    submap_000001.npz      ...

npz files are written through a temporary file and a rename before the journal line or manifest that
references them, so a process killed at any moment leaves an archive that reloads (`MapArchiveWriter`).
"""
from tools.map_archive.export import export_map, fuse_archive, write_ply
from tools.map_archive.format import FORMAT, MANIFEST_NAME, SCHEMA_VERSION
from tools.map_archive.info import map_info
from tools.map_archive.reader import check_integrity, integrity, iter_submaps, load_submap, read_manifest
from tools.map_archive.writer import MapArchiveWriter

__all__ = ["FORMAT", "MANIFEST_NAME", "SCHEMA_VERSION", "MapArchiveWriter", "check_integrity",
           "export_map", "fuse_archive", "integrity", "iter_submaps", "load_submap", "map_info",
           "read_manifest", "write_ply"]
