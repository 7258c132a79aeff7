"""`davio bench startup`: one short window per arm on a simulated preset, JSON contract."""
from __future__ import annotations

import json

import pytest

from tools.cli import main


@pytest.mark.slow
def test_startup_bench_json_contract(capsys, tmp_path):
    out_file = tmp_path / "startup.json"
    assert main(["bench", "startup", "--preset", "euroc", "--seconds", "6", "--window", "5", "--json",
                 "--arms", "feedforward,native,feedforward_only", "--out", str(out_file),
                 "--da3-param", "rotation_error_median_deg=0.1"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["arms"] == ["feedforward", "native", "feedforward_only"]
    for arm in out["arms"]:
        s = out[arm]
        assert s["windows"] == 1
        assert set(s) >= {"successes", "T_f_median", "T_q_median", "gravity_err_deg_median",
                          "velocity_err_median", "ate_median", "sources"}
        assert 0.0 < s["T_q_median"] <= 5.0
        assert sum(s["sources"].values()) == 1
    assert out["emulated_da3_overrides"] == {"rotation_error_median_deg": 0.1}
    rows = json.loads(out_file.read_text())["per_window"]
    # who published: the native arm never the feed-forward initializer, the FF-only arm only it,
    # and DAVIO whichever filter was ready first (both are armed)
    assert rows["native"][0]["source"].startswith("native:")
    assert rows["feedforward_only"][0]["source"] == "feedforward"
    ff, nat = rows["feedforward"][0], rows["native"][0]
    expect = "feedforward" if rows["feedforward_only"][0]["T_f"] < nat["T_f"] else nat["source"]
    assert ff["source"] == expect


def test_bad_override_is_a_clear_error(capsys):
    assert main(["bench", "startup", "--preset", "euroc", "--da3-param", "oops"]) == 1
    assert "NAME=NUMBER" in capsys.readouterr().err


@pytest.mark.parametrize("arms", ["feedforward,bogus", "native,native", ""])
def test_bad_arms_are_a_clear_error(capsys, arms):
    assert main(["bench", "startup", "--preset", "euroc", "--arms", arms]) == 1
    assert "--arms" in capsys.readouterr().err


def test_unknown_da3_preset_is_a_clear_error(capsys):
    assert main(["bench", "startup", "--preset", "euroc", "--da3", "huge"]) == 1
    assert "preset" in capsys.readouterr().err
