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


def test_a_reset_starts_a_new_trajectory_and_the_window_is_scored_on_the_good_one():
    """Two published segments (a restart after a divergence): the first drifts far from the truth,
    the second follows it exactly; the window succeeds with T_q at the second segment's start."""
    from types import SimpleNamespace

    import numpy as np

    from runtime.geometry.trajectory import PoseTrajectory
    from runtime.startup import Published
    from tools.benchmarks.startup import _score

    t = np.arange(0, 200) * 50_000_000  # 10 s at 20 Hz
    p_gt = np.c_[np.sin(t * 1e-9), 0.3 * t * 1e-9, np.zeros(t.size)]
    gt = PoseTrajectory(t, p_gt, np.repeat(np.eye(3)[None], t.size, 0))
    pub = []
    for k in range(20, 60):  # 1-3 s: drifting quadratically, 4 m off at the end
        pub.append(Published(int(t[k]), int(t[k]), np.eye(3), p_gt[k] + [(k - 20) ** 2 / 400.0, 0, 0],
                             np.zeros(3), "feedforward", 1, segment=0))
    for k in range(120, 200):  # 6-10 s: exact
        pub.append(Published(int(t[k]), int(t[k]), np.eye(3), p_gt[k] + [5.0, 0, 0], np.zeros(3),
                             "native:dynamic", 0, segment=1))
    report = SimpleNamespace(published_by="native:dynamic", candidates_diverged=0)
    pipe = SimpleNamespace(published=pub, startup=SimpleNamespace(report=report, publisher=None))
    row = _score(pipe, gt, 0, 10.0, 0.5)
    assert row["segments"] == 2 and row["success"]
    assert row["T_f"] == pytest.approx(1.0) and row["T_q"] == pytest.approx(6.0)
    assert row["ate"] < 1e-9
    one = _score(SimpleNamespace(published=pub[:40], startup=pipe.startup), gt, 0, 10.0, 0.5)
    assert not one["success"] and one["T_q"] == 10.0 and one["ate"] > 0.5
