"""The davio command: help lists every subcommand; info reports providers and numba."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tools.cli import build_parser, main


def test_help_lists_subcommands_with_options():
    parser = build_parser()
    text = parser.format_help()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) >= {"info", "bench"}
    for name, sp in sub.choices.items():
        assert name in text
        assert sp.format_help().startswith("usage: davio " + name)
        # the top-level help shows each command's usage with its options
        assert " ".join(sp.format_usage().replace("usage: ", "").split()) in text


def test_info_json_reports_providers_and_numba(capsys):
    assert main(["info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert "CPUExecutionProvider" in info["onnxruntime"]["available_providers"]
    assert "version" in info["numba"]
    assert info["packages"]["numpy"]


def test_console_script_entry_point_runs():
    out = subprocess.run([sys.executable, "-m", "tools.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("davio ")


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "usage: davio" in capsys.readouterr().out


def test_options_are_not_abbreviated_and_help_hides_none_defaults(capsys):
    """`--nat` is not taken for `--native-only` (a later option could make it mean something else), and
    no help line ends in '(default: None)'."""
    try:
        code = main(["run", "somewhere", "--nat"])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and "davio run: error: unrecognized arguments: --nat" in err
    assert "usage: davio run" in err                    # the command's usage, not the top-level one
    with pytest.raises(SystemExit):
        main(["eval", "ate", "a.tum", "b.tum", "--frob"])
    err = capsys.readouterr().err
    assert "davio eval ate: error: unrecognized arguments: --frob" in err and "usage: davio eval ate" in err
    # an unknown option is the parser's it was given to: before the subcommand, the command's
    for argv, owner in ((["eval", "--frob", "ate", "a.tum", "b.tum"], "davio eval: "),
                        (["map", "--frob", "info", "x"], "davio map: "),
                        (["--frob", "eval", "ate", "a.tum", "b.tum"], "davio: ")):
        with pytest.raises(SystemExit):
            main(argv)
        err = capsys.readouterr().err
        assert f"{owner}error: unrecognized arguments: --frob" in err, (argv, err)
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for sp in sub.choices.values():
        assert "(default: None)" not in sp.format_help()
    assert "(default: davio_run)" in " ".join(sub.choices["run"].format_help().split())


def test_building_the_options_imports_no_pipeline_model_runtime_or_simulator():
    """`davio --help` and every command's options are built without the heavy packages (the pipeline pulls in
    numba kernels and scipy, the simulator its renderer), so that a command starts at once; checked in a
    fresh interpreter, where nothing was imported before."""
    heavy = ["runtime.pipeline", "runtime.msckf.estimator", "drivers.sim.recording", "drivers.sim.render",
             "tools.calibrate.core", "numba", "scipy.optimize", "onnxruntime", "open3d", "matplotlib",
             "cv2", "drivers.live", "drivers.euroc", "models.emulated_da3.emulator"]
    code = ("import sys; from tools.cli import build_parser; build_parser(); "
            f"print([m for m in {heavy!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_version_builds_no_parser():
    """`davio --version` answers without reading any command's options (nor numpy), in a fresh interpreter."""
    from importlib.metadata import version

    code = ("import sys; from tools.cli import main; main(['--version']); "
            "print([m for m in sys.modules if m.startswith('tools.commands.') or m == 'numpy'])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == [f"davio {version('davio')}", "[]"]


def test_a_named_command_builds_its_own_options_only(capsys):
    parser = build_parser(only="listen")
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) >= {"run", "listen", "bench"}       # every command can still be named
    def options(name: str) -> set[str]:
        return {o for a in sub.choices[name]._actions for o in a.option_strings}

    assert "--tum" in options("listen")
    assert options("run") == {"-h", "--help"}                   # listed, not built
    # what main builds for each way of calling: the top-level help and options see every command's usage
    with pytest.raises(SystemExit):
        main(["--help", "run"])
    assert "usage of each command" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "--emulated" in capsys.readouterr().out


def test_an_os_error_no_command_handles_is_one_line(monkeypatch, capsys, tmp_path):
    """The last resort: what a command did not turn into its own message (a folder it may not read, found
    by the map-archive review) is the failing file and the system's reason, not a traceback."""
    import tools.commands.info as info

    def run(args):
        raise PermissionError(13, "Permission denied", str(tmp_path / "d0"))

    monkeypatch.setattr(info, "run", run)
    assert main(["info"]) == 1
    assert capsys.readouterr().err == f"davio info: error: {tmp_path / 'd0'}: Permission denied\n"


def test_an_os_error_while_interrupted_is_the_interruption_and_a_closed_pipe_is_quiet(monkeypatch, capsys):
    import tools.cli as cli
    import tools.commands.info as info

    def interrupted(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise OSError(5, "Input/output error", "/dev/ttyUSB0") from None   # e.g. a close while unwinding

    monkeypatch.setattr(info, "run", interrupted)
    assert main(["info"]) == 130
    assert capsys.readouterr().err == "davio info: interrupted (OSError)\n"
    dropped: list[bool] = []
    monkeypatch.setattr(cli, "_drop_stdout", lambda: dropped.append(True))

    def closed_pipe(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(info, "run", closed_pipe)
    assert main(["info"]) == 141 and dropped == [True]          # a reader that closed the pipe
    assert capsys.readouterr().err == ""


def test_a_rich_table_on_a_closed_pipe_exits_quietly_with_141(tmp_path: Path) -> None:
    """rich answered a reader that closed the pipe with its own SystemExit(1): an error exit."""
    from tests.tools.test_eval_io import random_traj
    from tools.evaluation import write_tum

    write_tum(tmp_path / "e.tum", random_traj(40))
    proc = subprocess.Popen([sys.executable, "-m", "tools.cli", "eval", "ate", str(tmp_path / "e.tum"),
                             str(tmp_path / "e.tum")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            cwd=Path(__file__).resolve().parents[2])
    proc.stdout.close()                         # the reader is gone before the table is printed
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 141 and err == b""
