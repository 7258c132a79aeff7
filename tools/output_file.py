"""Checks on a single output file a command is about to write (`map export --out`, `map view --out`,
`eval ate --save-aligned`), before any work: the writes are atomic renames, which would replace a device,
a FIFO or one of the command's own inputs as readily as a previous output.
"""
from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from pathlib import Path

from runtime.errors import ConfigError


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_output_file(path: Path, option: str, suffixes: tuple[str, ...], *, overwrite: bool = False,
                      replaceable: bool = False, inputs: Iterable[Path] = (),
                      protected_dirs: Iterable[Path] = (), new_folder: bool = False) -> bool:
    """ConfigError unless `path` may be written; returns True when it replaces an existing file.

    Args:
        path: the file to write.
        option: the option that named it, for the message (e.g. "--out").
        suffixes: accepted file name suffixes, lower case with the dot (".ply").
        overwrite: an existing regular file may be replaced (the user passed --overwrite).
        replaceable: an existing regular file may be replaced without --overwrite (the command's own
            default output, e.g. a run folder's map.ply).
        inputs: files the command reads; none of them may be the output.
        protected_dirs: folders the output must not be written into (e.g. the map archive itself).
        new_folder: a missing folder is fine (the command makes it): its nearest existing folder must
            be writable instead.
    """
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise ConfigError(f"{option} {path}: expected a {' or '.join(suffixes)} file, or an existing folder "
                          "to write into")
    for source in inputs:
        if _same_file(path, Path(source)):
            raise ConfigError(f"{option} {path}: is one of this command's inputs; choose another file")
    for folder in protected_dirs:
        if _same_file(path.parent, Path(folder)):
            raise ConfigError(f"{option} {path}: lies inside {folder}, which this command reads; choose "
                              "another folder")
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), path.parent)
        raise ConfigError(f"{option} {path}: {blocking} is a file, not a folder") from None
    except OSError as exc:
        raise ConfigError(f"{option} {path}: cannot check it ({exc.strerror or exc})") from None
    if st is None:
        if path.is_symlink():
            raise ConfigError(f"{option} {path}: is a broken symbolic link; remove it or choose another file")
        parent = path.parent
        if not parent.is_dir():
            if not new_folder:
                raise ConfigError(f"{option} {path}: folder {parent} does not exist")
            check_folder_can_be_made(parent, option, path)
            return False
        _probe_writable(path, option)
        return False
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{option} {path}: exists and is not a regular file (a device, FIFO or socket); "
                          "choose another file")
    if not (overwrite or replaceable):
        raise ConfigError(f"{option} {path}: exists; pass --overwrite to replace it, or choose another file")
    _probe_writable(path, option)
    return True


def check_folder_can_be_made(folder: Path, option: str, named: Path | None = None) -> None:
    """ConfigError unless `folder` is a writable folder or `mkdir(parents=True)` can make it: no broken
    symbolic link on the way, its nearest existing ancestor a folder a file can be created in (probed).
    `named` is what the option named (the file to write into the folder; default the folder)."""
    named = folder if named is None else named
    for f in (folder, *folder.parents):   # what `mkdir(parents=True)` would trip on
        if f.is_symlink() and not f.exists():
            raise ConfigError(f"{option} {named}: {f} is a broken symbolic link")
    base = next(f for f in (folder, *folder.parents) if f.exists() or f == f.parent)
    if not base.is_dir():
        raise ConfigError(f"{option} {named}: {base} is a file, not a folder")
    try:
        _probe_writable(base / ".davio-probe", option)
    except ConfigError as exc:
        if base == folder:
            raise
        raise ConfigError(f"{option} {named}: cannot create the folder {folder} (nothing can be written in "
                          f"{base})") from exc


def _probe_writable(path: Path, option: str) -> None:
    """ConfigError unless a file can be created beside `path` (the atomic write's temporary file): a
    permission check that also holds for root and for read-only or pseudo file systems."""
    import tempfile

    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".probe")
    except OSError as exc:
        raise ConfigError(f"{option} {path}: cannot write in {path.parent} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(tmp)
