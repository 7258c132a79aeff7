"""Config dataclasses <-> TOML: round trip, defaults, and errors naming the key."""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field

import pytest

from runtime.config_io import config_from_dict, config_to_dict, dump_toml, load_toml
from runtime.errors import ConfigError


@dataclass
class Inner:
    threshold: float = 0.25
    count: int = 100
    mode: str = "lmeds"


@dataclass
class Outer:
    name: str = "x"
    enabled: bool = True
    window: tuple[float, ...] = (0.2, 0.4)
    inner: Inner = field(default_factory=Inner)
    optional: float | None = None


def test_round_trip_through_toml_text(tmp_path):
    cfg = Outer(name="run", enabled=False, window=(1.0, 2.5), inner=Inner(threshold=0.5, count=7))
    path = tmp_path / "c.toml"
    path.write_text(dump_toml(cfg))
    assert tomllib.loads(path.read_text())["inner"]["count"] == 7
    assert load_toml(Outer, path) == cfg


def test_partial_dict_keeps_defaults_and_int_promotes_to_float():
    cfg = config_from_dict(Outer, {"inner": {"threshold": 1}})
    assert cfg.inner.threshold == 1.0 and isinstance(cfg.inner.threshold, float)
    assert cfg.inner.count == 100 and cfg.name == "x"
    assert config_to_dict(cfg)["inner"]["threshold"] == 1.0


@pytest.mark.parametrize(
    "data, needle",
    [
        ({"inner": {"treshold": 0.1}}, "inner.treshold"),
        ({"inner": {"count": 1.5}}, "inner.count"),
        ({"enabled": "yes"}, "enabled"),
        ({"inner": 3}, "inner"),
        ({"window": [1.0, "a"]}, "window[1]"),
    ],
)
def test_errors_name_the_key(data, needle):
    with pytest.raises(ConfigError) as exc:
        config_from_dict(Outer, data)
    assert needle in str(exc.value)


def test_bad_files_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_toml(Outer, tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("inner = [\n")
    with pytest.raises(ConfigError, match="bad.toml"):
        load_toml(Outer, bad)
