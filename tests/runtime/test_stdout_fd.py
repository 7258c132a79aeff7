"""runtime.stdout_fd: what C/C++ libraries write to descriptor 1 kept off a --json stdout, in fresh processes
(the real descriptors) and under pytest's captures."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from runtime.stdout_fd import json_stdout, stdout_to_stderr

ROOT = Path(__file__).resolve().parents[2]


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=str(ROOT), capture_output=True,
                          text=True, timeout=120)


def test_stdout_to_stderr_moves_descriptor_writes_and_restores_them(capfd) -> None:
    with stdout_to_stderr():
        os.write(1, b"from C++\n")
    os.write(1, b"after\n")
    with pytest.raises(ImportError), stdout_to_stderr():
        os.write(1, b"failing\n")
        raise ImportError("no such module")
    os.write(1, b"after the failure\n")
    captured = capfd.readouterr()
    assert captured.out == "after\nafter the failure\n" and captured.err == "from C++\nfailing\n"


def test_without_a_stdout_nothing_moves_and_nothing_fails(monkeypatch) -> None:
    monkeypatch.setattr(sys, "stdout", None)
    with stdout_to_stderr(), json_stdout():
        pass


def test_json_stdout_keeps_prints_on_stdout_and_library_lines_on_stderr() -> None:
    out = _python("""
        import os, sys
        from runtime.stdout_fd import json_stdout
        print("before")
        with json_stdout():
            os.write(1, b"[library] warning\\n")
            print('{"a": 1}')
        print("after")
        os.write(1, b"descriptor after\\n")
    """)
    assert out.returncode == 0, out.stderr
    assert out.stdout == 'before\n{"a": 1}\nafter\ndescriptor after\n' and out.stderr == "[library] warning\n"


def test_json_stdout_leaves_a_captured_stdout_alone(capsys) -> None:
    with json_stdout():
        print("captured")
    assert capsys.readouterr().out == "captured\n"


def test_a_commands_json_is_one_object_whatever_a_library_prints() -> None:
    """`davio info --json` with a library line printed to descriptor 1 while it runs (as depthai's and
    Open3D's loggers do): stdout still parses as one JSON object, the line is on stderr."""
    out = _python("""
        import os, sys
        import tools.commands.info as info
        collect = info.collect
        info.collect = lambda: (os.write(1, b"[Open3D WARNING] noise\\n"), collect())[1]
        from tools.cli import main
        sys.exit(main(["info", "--json"]))
    """)
    assert out.returncode == 0, out.stderr
    assert "python" in json.loads(out.stdout) and "[Open3D WARNING] noise" in out.stderr


def test_output_that_cannot_be_written_is_a_clear_error_not_lost() -> None:
    """A full disk under a --json output: the command says so and fails (Python's own exit flush would
    only print a traceback-like 'Exception ignored' and lose the output)."""
    if not Path("/dev/full").exists():
        pytest.skip("needs /dev/full (Linux)")
    with open("/dev/full", "w") as full:
        out = subprocess.run([sys.executable, "-m", "tools.cli", "info", "--json"], cwd=str(ROOT),
                             stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert out.returncode == 1
    assert out.stderr == "davio info: error: cannot write the output to stdout (No space left on device)\n"


def test_what_c_code_buffers_inside_the_block_goes_to_stderr() -> None:
    """A C printf without fflush inside the block (stdout a pipe: fully buffered) leaves on stderr, not at
    exit on stdout after the JSON."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    code = textwrap.dedent("""
        import ctypes
        from runtime.stdout_fd import json_stdout
        with json_stdout():
            ctypes.CDLL(None).printf(b"C printf, not flushed\\n")
            print('{"a": 1}')
    """)
    out = subprocess.run([sys.executable, "-c", code], cwd=str(ROOT), capture_output=True, text=True,
                         timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout == '{"a": 1}\n' and out.stderr == "C printf, not flushed\n"


def test_ctrl_c_while_the_output_is_flushed_still_restores_stdout() -> None:
    out = _python("""
        import os, sys
        import runtime.stdout_fd as stdout_fd
        calls = []
        def interrupted():
            calls.append(1)
            if len(calls) == 2:          # the flush at the block's end
                raise KeyboardInterrupt
        stdout_fd._flush_c_stdio = interrupted
        try:
            with stdout_fd.json_stdout():
                print("inside")
        except KeyboardInterrupt:
            pass
        os.write(1, b"descriptor 1 back\\n")
        print(sys.stdout is sys.__stdout__)
    """)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "inside\ndescriptor 1 back\nTrue\n" and out.stderr == ""


def test_a_plain_stand_in_for_stdout_on_descriptor_1_is_taken_as_it_is() -> None:
    """A program that set sys.stdout to its own object on descriptor 1 (no TextIOWrapper attributes)."""
    out = _python("""
        import os, sys
        from runtime.stdout_fd import json_stdout

        class Tee:
            def write(self, text):
                return os.write(1, text.encode())
            def flush(self):
                pass
            def fileno(self):
                return 1

        sys.stdout = Tee()
        with json_stdout():
            os.write(1, b"library line\\n")
            print("json")
        print("after")
    """)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "json\nafter\n" and out.stderr == "library line\n"


@pytest.mark.parametrize("argv", [["info", "--json"], ["--version"], ["info"]])
def test_a_closed_pipe_ends_the_command_quietly(argv: list[str]) -> None:
    """`davio ... | head`: the reader closed its end before the output was written. A --json output or the
    version line raised BrokenPipeError (a 'cannot write' error, a traceback); now nothing is said, and the
    plain table (rich's console, which exited 1 on its own) ends the same way."""
    r, w = os.pipe()
    os.close(r)                                       # the reader is gone before anything is written
    try:
        out = subprocess.run([sys.executable, "-m", "tools.cli", *argv], cwd=str(ROOT), stdout=w,
                             stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(w)
    assert out.stderr == ""
    assert out.returncode == 141
