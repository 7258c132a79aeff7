"""Command-line values that were accepted and then failed deep inside a run, or did something else than
asked (found by fuzzing every command's options): each is now refused naming the option."""
from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from runtime.errors import ConfigError
from tools.cli import main


def test_a_model_latency_beyond_an_hour_is_refused() -> None:
    """1e308 s ran for 9 s, then int(latency * 1e9) raised OverflowError in the scheduler."""
    from tools.commands.run import check_run_args

    args = argparse.Namespace(model_latency=1e308, model=None, seconds=None)
    with pytest.raises(ConfigError, match="--model-latency must be a number of seconds from 0 to 3600"):
        check_run_args(args)
    check_run_args(argparse.Namespace(model_latency=3600.0, model=None, seconds=None))


def test_a_gpu_memory_cap_beyond_any_gpu_is_refused() -> None:
    from tools.model_open import cuda_options

    with pytest.raises(ConfigError, match="--gpu-mem-limit 1e\\+308: give megabytes, from 256 to 1e\\+07"):
        cuda_options(argparse.Namespace(gpu_mem_limit=1e308))        # int(mb * 1e6) raised OverflowError
    assert cuda_options(argparse.Namespace(gpu_mem_limit=4096.0))["gpu_mem_limit"] == str(4096 * 10**6)


@pytest.mark.parametrize("out", [".", ""])
def test_the_current_folder_as_out_names_its_partial_folder_after_it(tmp_path: Path, monkeypatch, out):
    """`--out .` raised "PosixPath('.') has an empty name" making the partial folder's name."""
    from tools.run_folder import RunFolder

    run = tmp_path / "run"
    run.mkdir()
    monkeypatch.chdir(run)
    folder = RunFolder.prepare(out)
    assert folder.out == run and folder.path == tmp_path / "run.partial"


def test_listen_does_not_truncate_an_existing_tum_file(tmp_path: Path, capsys) -> None:
    """It opened --tum for writing: a run's final.tum named by mistake was emptied."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:     # a free port
        s.bind(("127.0.0.1", 0))
        url = f"udp://127.0.0.1:{s.getsockname()[1]}"
    tum = tmp_path / "final.tum"
    tum.write_text("1.0 0 0 0 0 0 0 1\n")
    assert main(["listen", url, "--tum", str(tum), "--seconds", "0.1"]) == 1
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert tum.read_text() == "1.0 0 0 0 0 0 0 1\n"
    assert main(["listen", url, "--tum", str(tum), "--seconds", "0.1", "--overwrite"]) == 0
    assert tum.read_text() == "# t[s] x y z qx qy qz qw\n"          # replaced: a header, nothing came


def test_an_evaluation_voxel_whose_keys_overflow_is_refused(tmp_path: Path, capsys) -> None:
    """1e-300 m overflowed the int64 voxel keys: both clouds collapsed to one point and a score came out."""
    cloud = tmp_path / "a.ply"
    cloud.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n0 0 0\n")
    assert main(["eval", "surface", str(cloud), str(cloud), "--voxel", "1e-300"]) == 1
    assert "--voxel" in capsys.readouterr().err


@pytest.mark.parametrize("opt", ["--width", "--height", "--fps"])
def test_a_zero_camera_size_or_rate_is_refused_not_replaced_by_the_default(opt: str) -> None:
    from tools.commands.live import open_device

    args = argparse.Namespace(source="uvc", width=None, height=None, fps=None)
    setattr(args, opt[2:], 0)
    with pytest.raises(ConfigError, match=f"{opt} must be > 0, got 0"):
        open_device(args, None)


@pytest.mark.parametrize("argv, said", [
    (["run", "--model", "", "rec"], "argument --model: an empty value"),     # ran the emulated default
    (["run", "--rig", " ", "rec"], "argument --rig: an empty value"),
    (["run", ""], "an empty operand"),
    (["info", "--model", ""], "argument --model: an empty value"),
    (["listen", "--tum", "", "udp://:9"], "argument --tum: an empty value"),   # recorded nothing
    (["eval", "ate", "a.tum", "b.tum", "--plot", ""], "argument --plot: an empty value"),
    (["calibrate", "rec", "--config", "", "--out", "c.yaml"], "argument --config: an empty value"),
    (["map", "export", "run1", "--out", ""], "argument --out: an empty value"),   # type=Path: '' was '.'
    (["map", "info", ""], "an empty operand"),                                    # read the current folder
    (["bench", "graph-solve", "--out="], "argument --out: an empty value"),
])
def test_an_empty_value_is_refused_not_taken_for_no_value(capsys, argv: list[str], said: str) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert said in capsys.readouterr().err


def test_a_negative_number_after_an_option_is_its_value_not_an_empty_one() -> None:
    from tools.cli import _empty_value

    assert _empty_value(["eval", "ate", "a", "b", "--offset", "-1"]) is None
    assert _empty_value(["run", "x", "-5", ""]) == ("", "an empty operand: give a value")


@pytest.mark.parametrize("argv, said", [
    (["map", "export", "run1", "--min-points", "0"], "argument --min-points: must be >= 1, got 0"),
    (["map", "view", "run1", "--min-points", "-2"], "argument --min-points: must be >= 1, got -2"),
    (["map", "align", "run1", "--to", "run0", "--candidates", "0"], "argument --candidates: must be >= 1"),
    (["map", "align", "run1", "--to", "run0", "--min-views", "1_0"], "argument --min-views: '1_0' is not"),
    (["simulate", "--motion-blur", "0", "--out", "x"], "argument --motion-blur: must be >= 1, got 0"),
    (["live", "oak", "--imu-rate", "0"], "argument --imu-rate: must be >= 1, got 0"),
    (["live", "oak", "--width", "-640"], "argument --width: must be >= 1, got -640"),
    (["bench", "openvins-sim", "--jobs", "0"], "argument --jobs: must be >= 1, got 0"),
    (["bench", "openvins-sim", "--seeds", "-1"], "argument --seeds: must be >= 0, got -1"),
    (["bench", "long-run", "--moved", "-1"], "argument --moved: must be >= 0, got -1"),
])
def test_a_count_out_of_range_is_refused_by_the_command_line(capsys, argv: list[str], said: str) -> None:
    """As the README says (exit 2 naming the option, before any work): these exited 1 from a later check,
    or were taken (int() reads '1_0' as 10)."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert said in capsys.readouterr().err
