"""Typed configuration: nested dataclasses <-> TOML/dicts, with errors that name the key.

Every threshold of the paper is a named dataclass field (defaults = the paper's numbers); a run
saves its resolved configuration beside its outputs (`config_to_dict`) and any run can be
reproduced from that file (`config_from_dict` / `load_toml`).
"""
from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any, TypeVar

from runtime.errors import ConfigError

T = TypeVar("T")


def config_to_dict(cfg: Any) -> dict:
    """A plain dict (TOML/JSON-serialisable) of a config dataclass, recursively."""
    if not dataclasses.is_dataclass(cfg):
        raise ConfigError(f"not a config dataclass: {type(cfg).__name__}")
    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            out[f.name] = config_to_dict(v)
        elif isinstance(v, tuple):
            out[f.name] = list(v)
        elif v is not None:
            out[f.name] = v
    return out


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", typing.Union)):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, key)
            except ConfigError as exc:
                errors.append(str(exc))
        if len(errors) == 1:      # an optional value (`float | None`): that type's own message
            raise ConfigError(errors[0])
        raise ConfigError(f"{key}: {value!r} matches none of {tp}")
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a table, got {type(value).__name__}")
        return _from_dict(tp, value, key)
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        inner = args[0] if args else Any
        items = [_coerce(v, inner, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        try:
            number = float(value)
        except OverflowError:
            raise ConfigError(f"{key}: {value} is too large for a number") from None
        if number != number:     # a NaN passes or fails every comparison: no section could check it
            raise ConfigError(f"{key} must be a number, got nan")
        return number
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    if typing.get_origin(tp) is typing.Literal:
        if value not in args:
            raise ConfigError(f"{key}: {value!r} is not one of {list(args)}")
        return value
    return value


#: options that no longer exist, with the one value they could hold: a config.toml written by an older run
#: still loads when it holds that value (nothing changes); any other value is refused
_RETIRED = {"msckf.integration": ("rk4", "the mean is always integrated with RK4")}


def _from_dict(cls: type[T], data: dict, prefix: str) -> T:
    hints = typing.get_type_hints(cls)
    data = dict(data)
    for key in [k for k in data if f"{prefix}.{k}" in _RETIRED]:
        only, why = _RETIRED[f"{prefix}.{key}"]
        if data[key] != only:
            raise ConfigError(f"{prefix}.{key} was removed ({why}); got {data[key]!r}, delete the line")
        del data[key]
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - names)
    if unknown:
        import difflib

        where = f"{prefix}." if prefix else ""
        named = [f"{where}{u} (did you mean {where}{close[0]}?)" if (close := difflib.get_close_matches(
            u, sorted(names), n=1, cutoff=0.75)) else where + u for u in unknown]
        raise ConfigError(f"unknown option(s) {', '.join(named)}; valid: {', '.join(sorted(names))}")
    kwargs = {k: _coerce(v, hints[k], f"{prefix}.{k}" if prefix else k) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from exc
    except ConfigError as exc:   # a section's own check: make sure the message names the section
        if prefix and not str(exc).startswith(prefix):
            raise ConfigError(f"[{prefix}] {exc}") from exc
        raise


def config_from_dict(cls: type[T], data: dict) -> T:
    """Build config dataclass `cls` from a (nested) dict; unspecified fields keep their defaults."""
    return _from_dict(cls, data, "")


#: Largest configuration file read, bytes (1 MiB; a full resolved config.toml is a few KiB).
MAX_CONFIG_BYTES = 1 << 20


def _toml_text(p: Path) -> tuple[str, str | None]:
    """(text, None) of a UTF-8 file, or (text with U+FFFD for bad bytes, 'byte 0x.. at offset N (line L)')."""
    if p.is_dir():
        raise ConfigError(f"{p}: is a folder, not a TOML file; give the file (e.g. a run's config.toml)")
    try:
        size = p.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError(f"{p}: file is {size} bytes, above the {MAX_CONFIG_BYTES} byte (1 MiB) limit "
                              "for configuration files; is this the TOML configuration?")
        raw = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{p}: configuration file not found") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read configuration file ({exc.strerror or exc})") from None
    try:
        return raw.decode("utf-8"), None
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        return raw.decode("utf-8", errors="replace"), f"byte 0x{raw[exc.start]:02x} at offset {exc.start} " \
                                                      f"(line {line}) is not UTF-8"


def _holds_replacement(value: object) -> bool:
    if isinstance(value, str):
        return "\ufffd" in value
    if isinstance(value, dict):
        return any(_holds_replacement(k) or _holds_replacement(v) for k, v in value.items())
    if isinstance(value, list):
        return any(_holds_replacement(v) for v in value)
    return False


def read_toml(path: str | Path) -> dict:
    """The parsed TOML file (ConfigError names the file).

    Folders, files above MAX_CONFIG_BYTES and binary files are refused with a ConfigError. The text
    must be UTF-8; bytes that are not (e.g. a Latin-1 comment) are tolerated only inside comments,
    which TOML discards, and are an error naming the byte's offset and line anywhere else.
    """
    import tomllib
    p = Path(path)
    text, bad = _toml_text(p)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        if bad is not None:
            raise ConfigError(f"{p}: not a UTF-8 TOML text file ({bad}); give a TOML configuration such "
                              "as a run's config.toml, saved as UTF-8") from None
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{p}: not valid TOML: arrays or tables nested too deeply") from None
    if bad is not None and _holds_replacement(data):
        raise ConfigError(f"{p}: {bad} and lies in a key or value; save the file as UTF-8")
    return data


def config_from_toml_dict(cls: type[T], data: dict, path: str | Path) -> T:
    """`config_from_dict` of a TOML file's `read_toml` result, its ConfigError naming the file."""
    try:
        return config_from_dict(cls, data)
    except ConfigError as exc:
        raise ConfigError(f"{Path(path)}: {exc}") from exc


def load_toml(cls: type[T], path: str | Path) -> T:
    """Read a TOML file into config dataclass `cls` (ConfigError names the file and key; file checks
    as `read_toml`)."""
    return config_from_toml_dict(cls, read_toml(path), path)


def toml_value(v: Any) -> str:
    """A scalar or list as TOML writes it (true, 0.5, "text", [1.0, 0.7])."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def dump_toml(cfg: Any) -> str:
    """TOML text of a config dataclass (tables for nested dataclasses)."""

    def emit(d: dict, path: list[str], lines: list[str]) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        tables = {k: v for k, v in d.items() if isinstance(v, dict)}
        if path and scalars:
            lines.append(f"[{'.'.join(path)}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {toml_value(v)}")
        if scalars:
            lines.append("")
        for k, v in tables.items():
            emit(v, path + [k], lines)

    lines: list[str] = []
    emit(config_to_dict(cfg), [], lines)
    return "\n".join(lines).rstrip() + "\n"
