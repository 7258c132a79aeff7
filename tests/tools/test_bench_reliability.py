"""`davio bench reliability`: every broken-input probe ends as expected (an error naming the fix, or a
counted repair) and no traceback escapes. The probes' expectations live in tools/benchmarks/reliability.py;
this keeps them true."""
from __future__ import annotations

import json

import pytest

from tools.cli import main

pytestmark = pytest.mark.slow


def test_every_probe_ends_as_expected_without_a_traceback(tmp_path, capsys):
    code = main(["bench", "reliability", "--keep", str(tmp_path), "--json"])
    result = json.loads(capsys.readouterr().out)
    bad = [(r["probe"], r["exit"], r["message"]) for r in result["probes"] if not r["as_expected"]]
    assert code == 0 and not bad and result["tracebacks"] == 0
    assert result["total"] >= 24
    kinds = {r["expected"].split(":")[0] for r in result["probes"]}
    assert kinds == {"error", "repair"}
