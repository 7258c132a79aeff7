"""Exception hierarchy of DAVIO: one root, one subclass per concern.

Every error raised on bad input names the file, line, key or sample that caused it.
"""
from __future__ import annotations


class DavioError(Exception):
    """Root of all DAVIO errors."""


class ConfigError(DavioError):
    """A configuration file or option is invalid."""


class CalibrationError(DavioError):
    """A rig calibration file is missing, malformed or inconsistent.

    Attributes:
        path: the calibration file (or None for in-memory data).
        key: the offending key (dotted path), or None.
    """

    def __init__(self, message: str, path: object | None = None, key: str | None = None) -> None:
        self.path = None if path is None else str(path)
        self.key = key
        where = ""
        if self.path is not None:
            where += f"{self.path}"
        if key is not None:
            where += f" [{key}]" if where else f"[{key}]"
        super().__init__(f"{where}: {message}" if where else message)


class DataError(DavioError):
    """A recording (dataset folder, bag, CSV, image) is malformed.

    Attributes:
        path: the file, or None.
        line: the 1-based line number in that file, or None.
    """

    def __init__(self, message: str, path: object | None = None, line: int | None = None) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        where = ""
        if self.path is not None:
            where = self.path + (f":{line}" if line is not None else "")
        super().__init__(f"{where}: {message}" if where else message)


class TrajectoryError(DataError):
    """A trajectory file or trajectory pair cannot be read, associated or aligned."""


class DeviceError(DavioError):
    """A live sensor is missing, unplugged or misbehaving."""


class ModelError(DavioError):
    """An ONNX model file is missing, corrupt or violates its contract."""


class EstimatorError(DavioError):
    """The estimator was used incorrectly (not for divergence, which is reported, not raised)."""


def caused_by_interrupt(exc: BaseException) -> bool:
    """True when `exc` is, or was raised while handling, a KeyboardInterrupt (Ctrl-C or SIGTERM).

    A Ctrl-C that lands inside a C extension (e.g. numba loading its kernel cache) surfaces as that
    extension's error (SystemError: "returned a result with an exception set") with the
    KeyboardInterrupt as its context; it is still an interruption.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False
