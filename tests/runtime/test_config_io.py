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


def test_latin1_byte_in_a_comment_is_tolerated(tmp_path):
    p = tmp_path / "c.toml"
    p.write_bytes(b"# r\xe9glages du 3 mai\nname = \"run\"\n")
    assert load_toml(Outer, p).name == "run"


def test_latin1_byte_in_a_value_names_offset_and_line(tmp_path):
    raw = b"# ok\nname = \"caf\xe9\"\n"
    p = tmp_path / "c.toml"
    p.write_bytes(raw)
    with pytest.raises(ConfigError) as err:
        load_toml(Outer, p)
    assert str(err.value) == (f"{p}: byte 0xe9 at offset {raw.index(0xE9)} (line 2) is not UTF-8 and lies "
                              "in a key or value; save the file as UTF-8")


def test_binary_file_folder_and_oversized_file_are_config_errors(tmp_path):
    binary = tmp_path / "model.onnx"
    binary.write_bytes(bytes(range(256)))
    with pytest.raises(ConfigError, match=r"model.onnx: not a UTF-8 TOML text file \(byte 0x80 at offset 1"):
        load_toml(Outer, binary)
    with pytest.raises(ConfigError, match="is a folder, not a TOML file"):
        load_toml(Outer, tmp_path)
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * (1 << 20) + b"\n")
    with pytest.raises(ConfigError, match=r"above the 1048576 byte \(1 MiB\) limit"):
        load_toml(Outer, big)


def test_deep_nesting_and_huge_numbers_are_config_errors(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("window = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ConfigError, match="nested too deeply"):
        load_toml(Outer, p)
    p.write_text("[inner]\nthreshold = 1" + "0" * 400 + "\n")
    with pytest.raises(ConfigError, match="inner.threshold: 1000.* is too large for a number"):
        load_toml(Outer, p)


def test_a_retired_option_with_its_only_value_still_loads_and_any_other_is_refused():
    """msckf.integration could only be "rk4"; an older run's config.toml still loads, a different value names
    the key (never silently dropped)."""
    from runtime.config import DavioConfig

    cfg = config_from_dict(DavioConfig, {"msckf": {"integration": "rk4", "max_clones": 9}})
    assert cfg.msckf.max_clones == 9 and not hasattr(cfg.msckf, "integration")
    with pytest.raises(ConfigError, match=r"msckf\.integration was removed"):
        config_from_dict(DavioConfig, {"msckf": {"integration": "euler"}})


def test_imu_noise_left_unset_is_not_written_and_a_set_value_round_trips(tmp_path):
    """The filter's IMU noise comes from the rig unless the configuration sets it: an unset density is not
    written to config.toml (reloading it keeps taking the rig's), a set one survives the round trip."""
    from runtime.config import DavioConfig
    from runtime.msckf.config import MsckfConfig

    path = tmp_path / "c.toml"
    path.write_text(dump_toml(DavioConfig()))
    assert "gyro_noise_density" not in tomllib.loads(path.read_text())["msckf"]
    cfg = DavioConfig(msckf=MsckfConfig(gyro_noise_density=5e-4))
    path.write_text(dump_toml(cfg))
    assert load_toml(DavioConfig, path).msckf.gyro_noise_density == 5e-4


def _saved_config_without(tmp_path, *keys: str):
    """A run's resolved config.toml (every section) with the given options' lines removed."""
    from runtime.config import DavioConfig

    lines = dump_toml(DavioConfig()).splitlines()
    path = tmp_path / "config.toml"
    path.write_text("\n".join(ln for ln in lines if ln.split(" = ")[0] not in keys) + "\n")
    return path


def test_a_saved_config_older_than_an_option_is_read_with_todays_default_and_a_note(tmp_path):
    from runtime.config import DavioConfig, load_davio_config

    path = _saved_config_without(tmp_path, "multiview_keep_unseen", "view_scales")
    notes: list[str] = []
    cfg = load_davio_config(path, warn=notes.append)
    assert cfg == DavioConfig()                               # today's defaults apply ...
    assert len(notes) == 1                                    # ... and the user is told which, once
    assert "mapping.multiview_keep_unseen" in notes[0]
    assert "[mapping] multiview_keep_unseen = false" in notes[0]
    assert "revisits.view_scales" in notes[0] and "[revisits] view_scales = [1.0]" in notes[0]
    assert "gauge_lambda_free" not in notes[0]                # present in the file: reproduced as saved


def test_a_complete_or_partial_config_gets_no_note(tmp_path):
    from runtime.config import load_davio_config

    notes: list[str] = []
    load_davio_config(_saved_config_without(tmp_path), warn=notes.append)
    partial = tmp_path / "partial.toml"
    partial.write_text("[mapping]\nvoxel_m = 0.05\n")         # hand-written: omits options on purpose
    assert load_davio_config(partial, warn=notes.append).mapping.voxel_m == 0.05
    assert notes == []


def test_every_newer_option_names_a_real_option_with_a_different_default():
    from runtime.config import NEWER_OPTIONS, DavioConfig

    today = config_to_dict(DavioConfig())
    for key, before in NEWER_OPTIONS.items():
        section, name = key.split(".")
        assert name in today[section] and today[section][name] != before, key


def test_a_saved_config_without_the_turning_initializer_section_is_whole_and_gets_a_note(tmp_path):
    """Runs saved before the turning-in-place initializer have no [turning_init] section: the file is
    still a whole saved configuration, and the note says how to run without it."""
    from runtime.config import DavioConfig, load_davio_config

    text = dump_toml(DavioConfig())
    head, rest = text.split("[turning_init]\n", 1)
    tail = rest[rest.index("\n["):] if "\n[" in rest else ""
    path = tmp_path / "config.toml"
    path.write_text(head + tail.lstrip("\n"))
    notes: list[str] = []
    assert load_davio_config(path, warn=notes.append) == DavioConfig()
    assert len(notes) == 1 and "[turning_init] enabled = false" in notes[0]


def test_a_config_saved_before_the_bring_up_sections_and_the_rotation_check_is_whole_and_gets_its_note(
        tmp_path):
    """Runs saved before the twenty-ninth session have no [bringup] / [rig_check] sections and no rotation
    check in [dynamic_init]: still a whole saved configuration, and the note says how the run behaved."""
    from runtime.config import DavioConfig, load_davio_config

    lines, skip = [], False
    for line in dump_toml(DavioConfig()).splitlines():
        if line.startswith("["):
            skip = line in ("[bringup]", "[rig_check]")
        if skip or line.split(" = ")[0] in ("max_rotation_mismatch_fraction", "rotation_check_max_ratio",
                                            "rotation_check_min_gyro_deg", "min_rotation_check_pairs",
                                            "rotation_mismatch_retry_s"):
            continue
        lines.append(line)
    path = tmp_path / "config.toml"
    path.write_text("\n".join(lines) + "\n")
    assert "[bringup]" not in path.read_text() and "max_rotation_mismatch_fraction" not in path.read_text()
    notes: list[str] = []
    assert load_davio_config(path, warn=notes.append) == DavioConfig()
    assert len(notes) == 1 and "[dynamic_init] max_rotation_mismatch_fraction = 1.0" in notes[0]
