"""The process's standard output at the file-descriptor level, for what C/C++ libraries print there:
depthai's log lines go to descriptor 1 whatever `sys.stdout` is, and would break a command's --json output
(one JSON object on stdout)."""
from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

from runtime.errors import DavioError


@contextlib.contextmanager
def stdout_to_stderr() -> Iterator[None]:
    """Descriptor 1 points at descriptor 2 within the block (Python's prints to a `sys.stdout` on
    descriptor 1 included); nothing moves when there is no stdout descriptor (closed)."""
    _flush(sys.stdout)
    try:
        saved = os.dup(1)
    except OSError:
        saved = None
    if saved is None:
        yield
        return
    try:
        os.dup2(2, 1)
        try:
            yield
        finally:
            _flush(sys.stdout)
    finally:
        os.dup2(saved, 1)
        os.close(saved)


@contextlib.contextmanager
def json_stdout() -> Iterator[None]:
    """For a command's --json: within the block DAVIO's prints (`sys.stdout`) still reach the process's
    stdout, while what C/C++ code writes to descriptor 1 (depthai's logger) goes to stderr; the C library's
    buffers are flushed at both ends, so nothing it held moves across. Open3D prints through Python's
    `sys.stdout` instead: its callers send that to stderr themselves. Nothing moves when `sys.stdout` is not
    descriptor 1 (a test's capture) or there is none. DavioError when what was printed could not be written
    at the end (a full disk, a closed pipe): said, not lost."""
    old = sys.stdout
    try:
        fd = old.fileno()
    except (AttributeError, OSError, ValueError):   # None, closed, or not a file (io.UnsupportedOperation)
        fd = None
    saved = None
    if fd == 1:
        _flush(old)
        try:
            saved = os.dup(1)
        except OSError:                              # descriptor 1 closed under a live sys.stdout
            saved = None
    if saved is None:
        yield
        return
    # as the stream it stands in for (a stand-in for sys.stdout may lack a TextIOWrapper's attributes)
    out = os.fdopen(saved, "w", buffering=1 if getattr(old, "line_buffering", False) else -1,
                    encoding=getattr(old, "encoding", None), errors=getattr(old, "errors", None))
    out.reconfigure(write_through=bool(getattr(old, "write_through", False)))
    _flush_c_stdio()
    os.dup2(2, 1)
    sys.stdout = out
    failed: OSError | ValueError | None = None
    try:
        yield
    finally:
        try:
            try:
                out.flush()
            except (OSError, ValueError) as exc:    # a full disk, a closed pipe
                failed = exc
            _flush_c_stdio()
        finally:                                     # also on Ctrl-C during the flush
            sys.stdout = old
            os.dup2(saved, 1)
            try:
                out.close()      # closes `saved` (also when its flush fails again)
            except (OSError, ValueError) as exc:
                failed = failed or exc
    if isinstance(failed, BrokenPipeError):    # the reader closed it (`| head`): the caller exits quietly
        raise failed
    if failed is not None:
        raise DavioError(f"cannot write the output to stdout ({getattr(failed, 'strerror', None) or failed})")


def _flush_c_stdio() -> None:
    """fflush(NULL): what C code printed and its library still buffers goes out to where descriptor 1 points
    now (otherwise at exit, wherever it points then)."""
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):     # no C library to reach (not a POSIX platform)
        pass


def _flush(stream: object) -> None:
    try:
        stream.flush()       # type: ignore[attr-defined]
    except (AttributeError, OSError, ValueError):   # None (closed at start), or closed since
        pass
