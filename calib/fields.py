"""Typed access to calibration YAML files; every failure is a CalibrationError naming file and key.

Rules shared by the EuRoC and Kalibr readers:
- an absent key is an error (a typo must not pass as withheld calibration);
- a key present with value ``null`` / ``~`` means withheld where the field allows it (None);
- numbers must be finite ints/floats (not strings, not booleans).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

from calib.camera import CameraModel, camera_class
from runtime.errors import CalibrationError

_MISSING = object()
#: The OpenCV/EuRoC directive line ("%YAML:1.0") that PyYAML rejects.
_OPENCV_DIRECTIVE = re.compile(r"\A(?:\ufeff)?%YAML:[^\n]*\n(?:---[^\n]*\n)?")


#: Largest calibration file read, bytes (1 MiB). Kalibr, EuRoC and OpenVINS files are a few KiB;
#: anything bigger is not a calibration file, and is refused before it is read or parsed.
MAX_CALIBRATION_BYTES = 1 << 20
#: Largest image width or height accepted in a calibration file, pixels.
MAX_IMAGE_SIDE = 1 << 16
#: Deepest nesting of YAML sequences / mappings accepted (calibration files need 4).
MAX_YAML_DEPTH = 32
#: Fast libyaml loader when PyYAML was built with it (same results, ~30x faster), else pure Python.
_BaseLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Loader(_BaseLoader):  # type: ignore[misc, valid-type]
    """Safe loader that also reads OpenCV's ``!!opencv-matrix`` tag as a plain mapping, YAML 1.2 numbers
    without a decimal point (``2e-5``, which YAML 1.1 reads as a string) as floats, and refuses a key
    given twice in one mapping (YAML 1.1 silently keeps the last)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: dict = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {key!r} given twice (first at line {seen[key] + 1})",
                        key_node.start_mark)
                seen[key] = key_node.start_mark.line
            except TypeError:   # an unhashable key: the base constructor reports it
                pass
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver("tag:yaml.org,2002:float",
                              re.compile(r"^[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$"),
                              list("-+0123456789."))


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict:
    return loader.construct_mapping(node, deep=True)


_Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)


def _nesting_depth(text: str) -> int:
    """Deepest nesting of sequences and mappings, from the parser's event stream (no objects built).

    Checked before construction: libyaml's composer recurses per level and overflows the C stack
    (a segmentation fault) at about 100,000 levels, which 200 kB of ``[`` can reach.
    """
    depth = deepest = 0
    for event in yaml.parse(text, Loader=_Loader):
        if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            depth += 1
            deepest = max(deepest, depth)
            if deepest > MAX_YAML_DEPTH:
                break
        elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            depth -= 1
    return deepest


def _first_bad_byte(raw: bytes) -> tuple[int, int, int]:
    """(offset, byte value, 1-based line) of the first byte that is not valid UTF-8 in ``raw``."""
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        return exc.start, raw[exc.start], raw.count(b"\n", 0, exc.start) + 1
    raise ValueError("raw is valid UTF-8")


def _holds_replacement(value: object) -> bool:
    """True when a parsed YAML value (keys included) holds U+FFFD, the mark of an undecodable byte."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, str):
            if "\ufffd" in v:
                return True
        elif isinstance(v, Mapping):
            stack.extend(v.keys())
            stack.extend(v.values())
        elif isinstance(v, (list, tuple, set)):
            stack.extend(v)
    return False


def read_yaml(path: str | os.PathLike) -> dict:
    """Parse a calibration YAML file (an OpenCV ``%YAML:1.0`` first line is stripped) to a mapping.

    Files above MAX_CALIBRATION_BYTES are refused unread. The text must be UTF-8, with one
    tolerance: bytes that are not UTF-8 (e.g. a Latin-1 ``é`` written by an editor) are accepted
    when they all lie in comments, which YAML discards, so nothing that is read depends on them.
    Such a byte in a key or value is a CalibrationError naming its offset and line.
    """
    p = Path(path)
    if not p.is_file():
        raise CalibrationError("calibration file not found" if not p.exists() else "not a file", p, None)
    try:
        size = p.stat().st_size
        if size > MAX_CALIBRATION_BYTES:
            raise CalibrationError(
                f"file is {size} bytes, above the {MAX_CALIBRATION_BYTES} byte (1 MiB) limit for "
                "calibration files; give the camchain / sensor.yaml itself", p, None)
        raw = p.read_bytes()
    except OSError as exc:
        raise CalibrationError(f"cannot read file ({exc.strerror or exc})", p, None) from None
    bad = None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        bad = _first_bad_byte(raw)
        text = raw.decode("utf-8", errors="replace")
    not_utf8 = "" if bad is None else (
        f"byte 0x{bad[1]:02x} at offset {bad[0]} (line {bad[2]}) is not UTF-8")
    text = _OPENCV_DIRECTIVE.sub("", text, count=1)
    try:
        depth = _nesting_depth(text)
        if depth > MAX_YAML_DEPTH:
            raise CalibrationError(f"YAML nested deeper than {MAX_YAML_DEPTH} levels; not a calibration file",
                                   p, None)
        data = yaml.load(text, Loader=_Loader)  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        if "nesting depth" in problem:   # PyYAML >= 6.0.3 stops deep nesting in its own parser first
            raise CalibrationError(f"YAML nested deeper than {MAX_YAML_DEPTH} levels; not a calibration file",
                                   p, None) from None
        also = f" ({not_utf8}; save the file as UTF-8)" if bad is not None else ""
        raise CalibrationError(f"invalid YAML{where}: {problem}{also}", p, None) from None
    except CalibrationError:
        raise
    except Exception as exc:  # PyYAML's constructors fail with ValueError, IndexError ('!!float' alone), ...
        raise CalibrationError(f"invalid YAML value: {type(exc).__name__}: {exc}", p, None) from None
    if bad is not None and _holds_replacement(data):
        raise CalibrationError(f"{not_utf8} and lies in a key or value; save the file as UTF-8", p, None)
    if not isinstance(data, dict):
        raise CalibrationError(f"expected a YAML mapping at top level, got {type(data).__name__}", p, None)
    return data


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write text to path through a temporary file in the same folder and a rename (usual permissions)."""
    from runtime.files import atomic_write_text

    atomic_write_text(path, text)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _as_float(value: int | float) -> float:
    """float(value), or inf for an integer too large for a float (reported as not finite)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


class Fields:
    """A mapping from a calibration file with checked, key-naming accessors.

    Args:
        path: the file the mapping came from (for error messages).
        data: the mapping.
        prefix: dotted key of this mapping inside the file ("" at top level).
    """

    def __init__(self, path: str | os.PathLike, data: Mapping, prefix: str = "") -> None:
        self.path = Path(path)
        self.data = data
        self.prefix = prefix

    def key(self, name: str) -> str:
        """Dotted key of ``name`` inside the file."""
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: str | None, message: str) -> CalibrationError:
        return CalibrationError(message, self.path, None if name is None else self.key(name))

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str, optional: bool = False) -> object:
        """The value under ``name``; absent: None if optional else CalibrationError."""
        value = self.data.get(name, _MISSING)
        if value is _MISSING:
            if optional:
                return None
            raise self.error(name, "required key is missing")
        return value

    def sub(self, name: str) -> Fields:
        """The nested mapping under ``name`` (required)."""
        value = self.raw(name)
        if not isinstance(value, Mapping):
            raise self.error(name, f"expected a mapping, got {type(value).__name__}")
        return Fields(self.path, value, self.key(name))

    def number(
        self, name: str, nullable: bool = False, optional: bool = False, positive: bool = False
    ) -> float | None:
        """A finite float; None when null (if nullable) or absent (if optional)."""
        value = self.raw(name, optional)
        if value is None:
            if nullable or optional:
                return None
            raise self.error(name, "must not be null")
        if not _is_number(value):
            raise self.error(name, f"expected a number, got {value!r}")
        f = _as_float(value)
        if not math.isfinite(f):
            raise self.error(name, f"must be finite, got {f}")
        if positive and f <= 0.0:
            raise self.error(name, f"must be positive, got {f}")
        return f

    def numbers(
        self, name: str, sizes: tuple[int, ...] | None = None, nullable: bool = False
    ) -> list[float] | None:
        """A list of finite floats whose length is one of ``sizes`` (any if None)."""
        value = self.raw(name)
        if value is None:
            if nullable:
                return None
            raise self.error(name, "must not be null")
        if not isinstance(value, list):
            raise self.error(name, f"expected a list of numbers, got {value!r}")
        if sizes is not None and len(value) not in sizes:
            want = " or ".join(map(str, sizes))
            raise self.error(name, f"expected {want} numbers, got {len(value)}")
        for i, v in enumerate(value):
            if not _is_number(v):
                raise self.error(name, f"element {i} is not a number: {v!r}")
            if not math.isfinite(_as_float(v)):
                raise self.error(name, f"element {i} is not finite: {v}")
        return [float(v) for v in value]

    def string(self, name: str) -> str:
        value = self.raw(name)
        if not isinstance(value, str):
            raise self.error(name, f"expected a string, got {value!r}")
        return value

    def matrix(self, name: str, rows: int, cols: int, nullable: bool = False) -> np.ndarray | None:
        """A rows x cols matrix from a list of rows, a flat list, or ``{rows, cols, data}`` (EuRoC/OpenCV)."""
        value = self.raw(name)
        if value is None:
            if nullable:
                return None
            raise self.error(name, "must not be null")
        if isinstance(value, Mapping):
            m = Fields(self.path, value, self.key(name))
            r = m.raw("rows")
            c = m.raw("cols")
            if (r, c) != (rows, cols):
                raise self.error(name, f"expected a {rows}x{cols} matrix, got rows={r!r} cols={c!r}")
            flat = m.numbers("data", (rows * cols,))
            assert flat is not None
            return np.array(flat).reshape(rows, cols)
        if not isinstance(value, list):
            raise self.error(name, f"expected a {rows}x{cols} matrix, got {value!r}")
        if all(isinstance(row, list) for row in value):
            if len(value) != rows or any(len(row) != cols for row in value):
                shape = f"{len(value)} rows of lengths {[len(row) for row in value]}"
                raise self.error(name, f"expected a {rows}x{cols} matrix, got {shape}")
            flat = [v for row in value for v in row]
        else:
            if len(value) != rows * cols:
                raise self.error(name, f"expected a {rows}x{cols} matrix, got a list of {len(value)} entries")
            flat = value
        for i, v in enumerate(flat):
            if not _is_number(v):
                raise self.error(name, f"entry {divmod(i, cols)} is not a number: {v!r}")
            if not math.isfinite(_as_float(v)):
                raise self.error(name, f"entry {divmod(i, cols)} is not finite: {v}")
        return np.array(flat, dtype=np.float64).reshape(rows, cols)


@contextmanager
def rekeyed(path: str | os.PathLike, keys: Mapping[str, str]) -> Iterator[None]:
    """Attach ``path`` and the file's own key to CalibrationErrors raised by in-memory validation.

    ``keys`` maps the validators' keys (e.g. ``intrinsics``, ``T_IC``) to dotted file keys.
    """
    try:
        yield
    except CalibrationError as err:
        if err.path is not None:
            raise
        message = str(err)
        prefix = f"[{err.key}]: "
        if message.startswith(prefix):
            message = message[len(prefix) :]
        key = keys.get(err.key or "", err.key)
        raise CalibrationError(message, path, key) from None


def read_camera(f: Fields, distortion_key: str) -> CameraModel | None:
    """Camera model from ``camera_model``, ``intrinsics`` [fx, fy, cx, cy], ``resolution`` [w, h],
    ``distortion_model`` and ``distortion_key`` of a camera block; None when intrinsics is null."""
    model = f.string("camera_model")
    if model.strip().lower() != "pinhole":
        raise f.error("camera_model", f"unsupported camera model {model!r} (supported: pinhole)")
    intrinsics = f.numbers("intrinsics", (4,), nullable=True)
    if intrinsics is None:
        return None
    resolution = f.raw("resolution")
    if (
        not isinstance(resolution, list)
        or len(resolution) != 2
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in resolution)
    ):
        raise f.error("resolution", f"expected [width, height] integers, got {resolution!r}")
    if not all(0 < v <= MAX_IMAGE_SIDE for v in resolution):
        raise f.error("resolution", f"expected [width, height] in pixels, 1 to {MAX_IMAGE_SIDE}, "
                                    f"got {[v if abs(v) < 10**12 else '(huge)' for v in resolution]}")
    with rekeyed(f.path, {"distortion_model": f.key("distortion_model")}):
        cls = camera_class(f.string("distortion_model"))
    coeffs = f.numbers(distortion_key, cls.distortion_sizes)
    assert coeffs is not None
    keys = {
        "resolution": f.key("resolution"),
        "intrinsics": f.key("intrinsics"),
        "distortion": f.key(distortion_key),
    }
    with rekeyed(f.path, keys):
        camera = cls(resolution[0], resolution[1], *intrinsics, coeffs)
    _check_principal_point(f, camera)
    _check_focal_length(f, camera)
    return camera


FOCAL_RANGE = (0.05, 100.0)
"""Focal lengths (px) per pixel of image width or height accepted: below, a pinhole field of view over 168
deg; above, under 0.6 deg (a focal length in the wrong unit or for another image size)."""


def _check_focal_length(f: Fields, cam: CameraModel) -> None:
    lo, hi = FOCAL_RANGE
    if lo * cam.width <= cam.fx <= hi * cam.width and lo * cam.height <= cam.fy <= hi * cam.height:
        return
    fov = 2.0 * np.degrees(np.arctan(cam.width / (2.0 * cam.fx)))
    raise f.error(
        "intrinsics",
        f"focal lengths (fx, fy) = ({cam.fx:g}, {cam.fy:g}) px are implausible for a "
        f"{cam.width}x{cam.height} image (a pinhole field of view of {fov:.3g} deg); they must be in pixels "
        "of this resolution",
    )


def _check_principal_point(f: Fields, cam: CameraModel) -> None:
    """Refuse a principal point outside the image ([-0.5, size - 0.5] with pixel-centre coordinates):
    it means swapped intrinsics or a resolution that belongs to another image size."""
    if -0.5 <= cam.cx <= cam.width - 0.5 and -0.5 <= cam.cy <= cam.height - 0.5:
        return
    raise f.error(
        "intrinsics",
        f"principal point (cx, cy) = ({cam.cx:g}, {cam.cy:g}) lies outside the {cam.width}x{cam.height} "
        "image; check the order [fx, fy, cx, cy] and that the resolution is [width, height]",
    )
