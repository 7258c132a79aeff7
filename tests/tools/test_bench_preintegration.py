"""`davio bench preintegration --json` prints one object with per-sample timings."""
from __future__ import annotations

import json

from tools.cli import main


def test_preintegration_bench_json(capsys):
    assert main(["bench", "preintegration", "--json", "--repeats", "1", "--seconds", "0.2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["per_sample_with_cov_us"] > 0 and out["per_sample_no_cov_us"] > 0
