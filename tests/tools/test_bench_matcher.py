"""`davio bench matcher` end to end on synthetic homography pairs (no data needed)."""

from __future__ import annotations

import json

from tools.cli import main


def test_matcher_bench_reports_precision_and_the_provider_of_each_backend(capsys):
    assert main(["bench", "matcher", "--source", "synthetic", "--pairs", "1", "--repeats", "1",
                 "--threads", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    res = out["results"]
    assert set(res) == {"xfeat", "orb"}
    assert res["xfeat"]["provider"] == "CPUExecutionProvider" and res["orb"]["provider"] == "opencv"
    for r in res.values():  # against the homography's ground truth, after LK refinement
        assert r["matches_per_pair"] > 100 and r["precision"] > 0.9
