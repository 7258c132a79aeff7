"""`gpu_inventory` against stand-in `nvidia-smi` programs on PATH (CI has no GPU)."""

from __future__ import annotations

import json
import os
import stat

import pytest

from models.gpu_inventory import gpu_inventory
from tools.cli import main


def fake_smi(tmp_path, monkeypatch, body: str) -> None:
    exe = tmp_path / "nvidia-smi"
    exe.write_text("#!/bin/sh\n" + body + "\n")
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ.get('PATH', '')}")


def test_two_gpus_one_with_a_comma_in_its_name(tmp_path, monkeypatch):
    # what nvidia-smi --query-gpu=index,name,memory.total,memory.used --format=csv,noheader,nounits prints
    fake_smi(tmp_path, monkeypatch, 'echo "0, NVIDIA H100 80GB HBM3, 81559, 3765"\n'
                                    'echo "1, Orin (nvgpu), rev 2, 7620, 0"')
    gpus, note = gpu_inventory()
    assert note == ""
    assert gpus == [
        {"index": 0, "name": "NVIDIA H100 80GB HBM3", "memory_total_mib": 81559, "memory_used_mib": 3765},
        {"index": 1, "name": "Orin (nvgpu), rev 2", "memory_total_mib": 7620, "memory_used_mib": 0},
    ]


@pytest.mark.parametrize("body, words", [
    ('echo "NVIDIA-SMI has failed because it couldn\'t communicate with the NVIDIA driver." >&2; exit 9',
     "nvidia-smi failed (exit 9): NVIDIA-SMI has failed"),
    ('echo "0, GPU in a bad state, [N/A], [N/A]"', "1 line(s) of nvidia-smi not understood"),
    ("exit 0", "nvidia-smi lists no GPU"),
    ("exec sleep 5", "did not answer within 0.5 s"),
])
def test_a_failing_or_odd_nvidia_smi_is_a_note_not_an_error(tmp_path, monkeypatch, body, words):
    fake_smi(tmp_path, monkeypatch, body)
    gpus, note = gpu_inventory(timeout_s=0.5)
    assert gpus == [] and words in note


def test_info_lists_the_gpus(tmp_path, monkeypatch, capsys):
    fake_smi(tmp_path, monkeypatch, 'echo "0, NVIDIA GeForce RTX 3060 Laptop GPU, 6144, 512"')
    assert main(["info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["gpus"]["devices"][0]["name"] == "NVIDIA GeForce RTX 3060 Laptop GPU"
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    gpus, note = gpu_inventory()
    assert gpus == [] and note == "nvidia-smi not found"
