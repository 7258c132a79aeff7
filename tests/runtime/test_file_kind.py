"""runtime.file_kind: what a path given as a file is, when it is not one."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from runtime.file_kind import FOLDER, MISSING, file_problem


def test_each_kind_of_non_file_is_named(tmp_path: Path) -> None:
    (tmp_path / "f.txt").write_text("x")
    os.symlink("f.txt", tmp_path / "good_link")
    os.symlink("nowhere", tmp_path / "broken")
    os.symlink("loop", tmp_path / "loop")
    assert file_problem(tmp_path / "f.txt") is None and file_problem(tmp_path / "good_link") is None
    assert file_problem(tmp_path / "absent") == MISSING
    assert file_problem(tmp_path / "f.txt" / "below") == MISSING       # a file where a folder should be
    assert file_problem(tmp_path) == FOLDER
    assert file_problem(tmp_path / "broken") == "is a broken symbolic link"
    assert file_problem(tmp_path / "loop") == "is a symbolic link loop"
    assert file_problem("a\0b") == MISSING


@pytest.mark.skipif(not os.path.exists("/dev/null"), reason="needs /dev/null")
def test_a_device_is_not_a_regular_file() -> None:
    assert file_problem("/dev/null") == "is not a regular file (a device, pipe or socket)"
