"""`davio bench startup`: one short window per arm on a simulated preset, JSON contract."""
from __future__ import annotations

import json

import pytest

from tools.cli import main


@pytest.mark.slow
def test_startup_bench_json_contract(capsys):
    assert main(["bench", "startup", "--preset", "euroc", "--seconds", "9", "--window", "8", "--json",
                 "--da3-param", "rotation_error_median_deg=0.1"]) == 0
    out = json.loads(capsys.readouterr().out)
    for arm in ("feedforward", "native"):
        s = out[arm]
        assert s["windows"] == 1
        assert set(s) >= {"successes", "T_f_median", "T_q_median", "gravity_err_deg_median",
                          "velocity_err_median", "ate_median"}
        assert 0.0 < s["T_q_median"] <= 8.0
    assert out["emulated_da3_overrides"] == {"rotation_error_median_deg": 0.1}


def test_bad_override_is_a_clear_error(capsys):
    assert main(["bench", "startup", "--preset", "euroc", "--da3-param", "oops"]) == 1
    assert "NAME=NUMBER" in capsys.readouterr().err
