"""Why a path given as an input file is not one, in words a message can carry.

`Path.is_file()` is False alike for a missing file, a folder, a broken or looping symbolic link and a
device; a reader that says "missing" for each sends its user looking in the wrong place.
"""
from __future__ import annotations

import errno
import os
import stat

MISSING = "does not exist"
FOLDER = "is a folder, not a file"


def file_problem(path: str | os.PathLike) -> str | None:
    """None when `path` is a regular file (symbolic links followed), else why not: MISSING, FOLDER,
    "is a broken symbolic link", "is a symbolic link loop", "is not a regular file (a device, pipe or
    socket)", or the system's reason (e.g. "Permission denied" on a folder above it)."""
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "is a symbolic link loop"
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            try:
                os.lstat(path)              # the link itself is there: it points nowhere
                return "is a broken symbolic link"
            except OSError:
                return MISSING
        return exc.strerror or str(exc)
    except ValueError:                      # an embedded NUL byte
        return MISSING
    if stat.S_ISDIR(mode):
        return FOLDER
    if not stat.S_ISREG(mode):
        return "is not a regular file (a device, pipe or socket)"
    return None
