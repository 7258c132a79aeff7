"""Out-of-range values in the mapping, startup, graph, revisits and bring-up sections are refused when
the configuration is read, naming the key (they used to fail deep inside a run, or pass silently)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from models.matcher.pnp import PnPGates
from runtime.bringup import BringUpConfig
from runtime.config import DavioConfig, load_davio_config
from runtime.config_io import dump_toml
from runtime.errors import ConfigError
from runtime.graph.config import GraphConfig, RevisitConfig
from runtime.mapping.config import MappingConfig
from runtime.startup import StartupConfig


@pytest.mark.parametrize("toml,message", [
    ("[mapping]\nvoxel_m = -0.04", "mapping.voxel_m must be in [0.005, 10], got -0.04"),
    ("[mapping]\nvoxel_m = 0.001", "mapping.voxel_m must be in [0.005, 10]"),
    ("[mapping]\nkeyframe_spacing_s = 0.0", "mapping.keyframe_spacing_s must be a finite number > 0"),
    ("[mapping]\nshared_images = 5", "mapping.shared_images must be below mapping.window_images (5), got 5"),
    ("[mapping]\nconf_percentile = 100.0", "mapping.conf_percentile must be in [0, 100)"),
    ("[mapping]\nframe_scale_pair_offsets = [1, 0]", "mapping.frame_scale_pair_offsets must be a list"),
    ("[startup]\nwindow_images = 0", "startup.window_images must be an integer >= 3, got 0"),
    ("[startup]\nwindow_tolerance_s = 0.1", "startup.window_tolerance_s must be below half"),
    ("[startup]\nbuffer_s = nan", "startup.buffer_s must be a number, got nan"),
    ("[graph]\nhuber_threshold = 0.0", "graph.huber_threshold must be > 0"),
    ("[graph]\nmax_resident_nodes = 1", "graph.max_resident_nodes must be an integer >= 2"),
    ("[revisits]\nmin_view_overlap = 1.5", "revisits.min_view_overlap must be in [0, 1]"),
    ("[revisits]\nmin_coverage_cells = 17", "revisits.min_coverage_cells must be at most"),
    ("[revisits.pnp]\nconfidence = 1.0", "revisits.pnp.confidence must be in (0, 1)"),
    ("[msckf]\nmax_clones = 1", "[msckf] max_clones must be >= 2, got 1"),   # the section is named
    ("[tracker]\nnum_ptss = 150", "unknown option(s) tracker.num_ptss (did you mean tracker.num_pts?)"),
    ("[tracker]\nmin_px_dist = nan", "tracker.min_px_dist must be a number, got nan"),
    ("[tracker]\nransac_confidence = 0.0", "tracker.ransac_confidence must be in (0, 1], got 0.0"),
    ("[msckf]\nimu_buffer_s = nan", "msckf.imu_buffer_s must be a number, got nan"),
    ("[msckf]\nimu_buffer_s = -1.0", "msckf.imu_buffer_s must be a finite number > 0, got -1.0"),
    ("[msckf]\nmax_velocity = -1.0", "msckf.max_velocity must be a finite number > 0"),
    ("[msckf]\ninit_sigma_pos = inf", "msckf.init_sigma_pos must be a finite number, got inf"),
    ("[static_init]\nsigma_p = nan", "static_init.sigma_p must be a number, got nan"),
    ("[static_init]\nsigma_v = 0.0", "static_init.sigma_v must be a finite number > 0"),
    ("use_dynamic_int = true", "use_dynamic_int (did you mean use_dynamic_init?)"),
    # every float of every section, also those no check names (a NaN in a list too)
    ("[dynamic_init]\ninflation_p = nan", "dynamic_init.inflation_p must be a number, got nan"),
    ("[dynamic_init]\nbias_g_prior = [0.0, nan, 0.0]",
     "dynamic_init.bias_g_prior[1] must be a number, got nan"),
    ("[turning_init]\nsigma_theta = nan", "turning_init.sigma_theta must be a number, got nan"),
    ("[msckf]\ngyro_noise_density = nan", "msckf.gyro_noise_density must be a number, got nan"),  # optional
    ("[ffinit]\nmin_inlier_threshold = nan", "ffinit.min_inlier_threshold must be a number, got nan"),
    ("[tracker]\nequalization = 'clahe'\nclahe_tiles = 0",
     "tracker.clahe_tiles must be an integer >= 1, got 0"),
    ("[tracker]\nlk_max_iterations = -1", "tracker.lk_max_iterations must be an integer >= 1, got -1"),
    ("[tracker]\nborder_px = -1", "tracker.border_px must be an integer >= 0, got -1"),
    ("[tracker]\nfast_threshold_min = -5", "tracker.fast_threshold_min must be an integer >= 0, got -5"),
    ("[dynamic_init]\nmin_deg = -1.0", "dynamic_init.min_deg must be a finite number >= 0, got -1.0"),
    ("[dynamic_init]\nsigma_bg_prior = 0.0",
     "dynamic_init.sigma_bg_prior must be a finite number > 0, got 0.0"),
    ("[dynamic_init]\ninflation_v = inf", "dynamic_init.inflation_v must be a finite number, got inf"),
    ("[dynamic_init]\nmin_window_fraction = 0.0",
     "dynamic_init.min_window_fraction must be in (0, 1], got 0.0"),
    ("[turning_init]\nsigma_p = -0.05", "turning_init.sigma_p must be a finite number > 0, got -0.05"),
    ("[turning_init]\nmin_rotation_deg = inf",
     "turning_init.min_rotation_deg must be a finite number, got inf"),
    ("[ffinit]\nnum_images = -1", "ffinit.num_images must be an integer >= 2, got -1"),
    ("[ffinit]\ngrid_rows = 0", "ffinit.grid_rows must be an integer >= 1, got 0"),
    ("[ffinit]\nmin_images = 6", "ffinit.min_images (6) must be at most ffinit.num_images (5)"),
    ("[ffinit]\nsigma_scale = 0.0", "ffinit.sigma_scale must be a finite number > 0, got 0.0"),
    ("[ffinit]\nconf_percentile = 100.0", "ffinit.conf_percentile must be in [0, 100)"),
    ("[ffinit]\nmin_inlier_fraction = 1.5", "ffinit.min_inlier_fraction must be in [0, 1], got 1.5"),
])
def test_out_of_range_values_name_the_key(tmp_path: Path, toml: str, message: str) -> None:
    path = tmp_path / "c.toml"
    path.write_text(toml + "\n")
    with pytest.raises(ConfigError) as err:
        load_davio_config(path)
    assert message in str(err.value)


def test_a_nan_set_in_code_is_refused_and_an_upper_gate_may_be_switched_off_with_inf() -> None:
    from runtime.ffinit.config import FFInitConfig
    from runtime.msckf.init_dynamic import DynamicInitConfig
    from runtime.msckf.init_turning import TurningInitConfig

    with pytest.raises(ConfigError, match="dynamic_init.min_parallax_deg must be a finite number, got nan"):
        DynamicInitConfig(min_parallax_deg=math.nan)    # NaN compares false: the gate was off, unsaid
    with pytest.raises(ConfigError, match="ffinit.max_velocity must be a finite number, got nan"):
        FFInitConfig(max_velocity=math.nan)
    with pytest.raises(ConfigError, match="turning_init.window_time_s must be a finite number, got nan"):
        TurningInitConfig(window_time_s=math.nan)
    DynamicInitConfig(max_condition=math.inf, max_reprojection_rms_px=math.inf)
    FFInitConfig(max_velocity=math.inf, max_scale_uncertainty=math.inf)
    TurningInitConfig(max_disparity_px=math.inf)


def test_defaults_and_the_boundaries_pass(tmp_path: Path) -> None:
    (tmp_path / "full.toml").write_text(dump_toml(DavioConfig()))
    assert load_davio_config(tmp_path / "full.toml") == DavioConfig()   # every default passes its checks
    # boundary values that mean something: 0 = off, inf = plain quadratic loss, None = process setting
    MappingConfig(voxel_m=0.005, shared_images=0, min_baseline_m=0.0, max_multiview_failed_fraction=1.0)
    MappingConfig(voxel_m=10.0, window_images=2, shared_images=1, conf_percentile=0.0)
    StartupConfig(extend_refused_s=0.0, catch_up_s=0.0, window_images=3)
    GraphConfig(huber_threshold=math.inf, blas_threads=None, drift_trans_sigma_per_m=0.0)
    RevisitConfig(min_coverage_cells=16, min_view_overlap=0.0, max_views=0)
    PnPGates(min_inlier_fraction=1.0, confidence=0.5, iterations=np.int64(100))
    for bad in (dict(iterations=1.5), dict(min_inliers=4.5), dict(min_matches=True), dict(confidence=1.0)):
        with pytest.raises(ConfigError, match="revisits.pnp"):
            PnPGates(**bad)
    BringUpConfig(window_gap_s=0.0, min_rotation_deg=0.0)
    for bad in (dict(voxel_m=0.0049), dict(voxel_m=math.inf), dict(window_images=1), dict(pixel_stride=0)):
        with pytest.raises(ConfigError):
            MappingConfig(**bad)
    for bad in (dict(window_images=2), dict(max_candidates=0), dict(window_spacing_s=0.0),
                dict(replay_batch=0)):
        with pytest.raises(ConfigError):
            StartupConfig(**bad)
    with pytest.raises(ConfigError, match="bringup.window_images"):
        BringUpConfig(window_images=2)
    with pytest.raises(ConfigError, match="graph.blas_threads"):
        GraphConfig(blas_threads=0)
    # numpy numbers are numbers (a configuration built in code from arrays)
    MappingConfig(window_images=np.int64(5), voxel_m=np.float32(0.04))
    with pytest.raises(ConfigError, match="mapping.window_images must be an integer >= 2, got np.int64"):
        MappingConfig(window_images=np.int64(1))


def test_an_imu_outage_bound_below_the_gap_bound_is_refused() -> None:
    from runtime.errors import ConfigError
    from runtime.msckf.config import MsckfConfig

    with pytest.raises(ConfigError, match=r"max_imu_outage_s \(0.02 s\) must be at least msckf.max_imu_gap"):
        MsckfConfig(max_imu_outage_s=0.02)
    assert MsckfConfig(max_imu_outage_s=0.05).max_imu_outage_s == 0.05
