"""A run's gyroscope rate quantiles in constant memory, against numpy's; the console's unit line."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.imu.rate_quantiles import GYRO_UNITS_P90_RAD_S, RateQuantiles


@pytest.mark.parametrize("scale", [0.05, 0.4, 3.0, 180 / np.pi * 0.4])
def test_quantiles_within_half_a_bin_of_numpys(scale: float) -> None:
    rng = np.random.default_rng(1)
    g = rng.normal(0, scale, (5001, 3))
    g[::97] = np.nan                                   # non-finite samples are not counted
    rm = RateQuantiles()
    for x in g:
        rm.add(*x)
    norms = np.linalg.norm(g[np.isfinite(g).all(axis=1)], axis=1)
    assert rm.n == len(norms)
    for q in (0.1, 0.5, 0.9):
        assert rm.quantile(q) == pytest.approx(np.quantile(norms, q), rel=0.062)


def test_a_run_mostly_at_rest_in_deg_s_is_flagged_by_its_90th_percentile() -> None:
    """60 % at rest (a bias of 0.005 rad/s), then turning at about 0.5 rad/s: the median is the bias, in
    deg/s too, but the 90th percentile of the deg/s copy is far above the limit, the rad/s one far below."""
    rm, rm_deg = RateQuantiles(), RateQuantiles()
    rng = np.random.default_rng(2)
    samples = np.concatenate([rng.normal(0.005, 0.001, (1200, 3)), rng.normal(0, 0.3, (800, 3))])
    for x in samples:
        rm.add(*x)
        rm_deg.add(*np.degrees(x))
    assert rm_deg.quantile(0.5) < 1.0
    assert rm.quantile(0.9) < 1.0 < GYRO_UNITS_P90_RAD_S < 20 < rm_deg.quantile(0.9)
    assert RateQuantiles().quantile(0.5) is None


def test_the_console_says_a_likely_deg_s_gyroscope() -> None:
    from tools.run_summary import recovery_lines as _recovery_lines

    report = {"pipeline": {"tracking": {"gyro_rate_p90_rad_s": 27.3}}}
    assert any(line.startswith("GYROSCOPE UNITS? a tenth of the run turns faster than 27.3 rad/s")
               for line in _recovery_lines(report))
    report["pipeline"]["tracking"]["gyro_rate_p90_rad_s"] = 0.9
    assert not any("GYROSCOPE UNITS" in line for line in _recovery_lines(report))


@pytest.mark.shared_data
@pytest.mark.parametrize("sequence", ["MH_03_medium", "V1_02_medium"])
def test_real_euroc_flights_pass_and_their_deg_s_copies_are_flagged(sequence: str) -> None:
    from conftest import shared_path

    imu = np.loadtxt(shared_path("euroc_imu_gt", sequence, "imu0.csv"), delimiter=",", comments="#")
    rm, rm_deg = RateQuantiles(), RateQuantiles()
    for g in imu[:, 1:4]:
        rm.add(*g)
        rm_deg.add(*np.degrees(g))
    assert rm.quantile(0.9) < 1.5 and rm_deg.quantile(0.9) > 2 * GYRO_UNITS_P90_RAD_S
