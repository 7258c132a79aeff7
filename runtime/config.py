"""The one configuration of a DAVIO run: nested dataclasses whose defaults are the paper's (and
OpenVINS EuRoC's) numbers, loadable from and saved to a single TOML file (runtime.config_io)."""
from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path

from runtime.bringup import BringUpConfig
from runtime.config_io import config_from_toml_dict, config_to_dict, read_toml, toml_value
from runtime.ffinit.config import FFInitConfig
from runtime.graph.config import GraphConfig, RevisitConfig
from runtime.mapping.config import MappingConfig
from runtime.msckf.config import MsckfConfig
from runtime.msckf.init_dynamic import DynamicInitConfig
from runtime.msckf.init_static import StaticInitConfig
from runtime.msckf.init_turning import TurningInitConfig
from runtime.msckf.tracker import TrackerConfig
from runtime.rig_check import RigCheckConfig
from runtime.startup import StartupConfig


@dataclass
class DavioConfig:
    """Everything a run needs besides the rig, the recording and the model file."""

    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    """KLT front-end."""
    msckf: MsckfConfig = field(default_factory=MsckfConfig)
    """The filter (OpenVINS EuRoC monocular defaults)."""
    static_init: StaticInitConfig = field(default_factory=StaticInitConfig)
    """Native static initializer (standing still; with no zero-velocity update, then a jerk)."""
    dynamic_init: DynamicInitConfig = field(default_factory=DynamicInitConfig)
    """Native dynamic initializer."""
    use_dynamic_init: bool = True
    """Arm the native dynamic initializer beside the static one (DESIGN: static + dynamic, always armed).
    OpenVINS's EuRoC configuration leaves it off; without it a filter that starts, or is reset, while
    moving never re-initializes unless the feed-forward start-up succeeds, e.g. after a calibration-
    withheld bring-up on a moving rig."""
    turning_init: TurningInitConfig = field(default_factory=TurningInitConfig)
    """Native turning-in-place initializer (the static one's rule with the rotation removed; not in
    OpenVINS): a body that turns on the spot at start-up starts at zero velocity."""
    startup: StartupConfig = field(default_factory=StartupConfig)
    """Buffered-replay handoff."""
    ffinit: FFInitConfig = field(default_factory=FFInitConfig)
    """Feed-forward initializer thresholds."""
    mapping: MappingConfig = field(default_factory=MappingConfig)
    """Pose-conditioned dense mapping (runs whenever a depth model is given)."""
    graph: GraphConfig = field(default_factory=GraphConfig)
    """The submap graph (drift model, point covariance, scale prior, Huber, LM iterations)."""
    revisits: RevisitConfig = field(default_factory=RevisitConfig)
    """Revisit candidates and their verification gates."""
    bringup: BringUpConfig = field(default_factory=BringUpConfig)
    """Calibration-withheld bring-up (hand-eye windows, their gates; runs only while T_IC is unknown)."""
    rig_check: RigCheckConfig = field(default_factory=RigCheckConfig)
    """Model-free rig checks from the tracked features (gyro scale, camera-IMU rotation; runs without the
    feed-forward start-up)."""


NEWER_OPTIONS: dict[str, object] = {
    "mapping.multiview_keep_unseen": False,
    "mapping.max_multiview_failed_fraction": 1.0,
    "graph.gauge_lambda_free": False,
    "revisits.view_scales": [1.0],
    "turning_init.enabled": False,
    "dynamic_init.max_rotation_mismatch_fraction": 1.0,
}
"""Options whose default differs from what DAVIO did before the option existed, with that earlier
behaviour's value: a run's saved config.toml written before one of them was added takes today's default
when it is read back, and `load_davio_config` says so (with the line that reproduces the old run)."""


NEWER_SECTIONS = {"turning_init", "bringup", "rig_check"}
"""Sections added after runs were first saved: a saved config.toml without them is still a whole one."""


def newer_option_notes(data: dict) -> list[str]:
    """Notes for a configuration dict that is a run's saved, resolved config.toml (it holds every section
    of DavioConfig) written before some of NEWER_OPTIONS existed: one line per missing option, with today's
    default and the value that reproduces the earlier run. A partial, hand-written file gets none."""
    sections = {f.name for f in fields(DavioConfig) if f.default_factory is not MISSING}
    if not sections - NEWER_SECTIONS <= set(data):
        return []
    today = config_to_dict(DavioConfig())
    notes = []
    for key, before in NEWER_OPTIONS.items():
        section, name = key.split(".")
        if name in data.get(section, {}):
            continue
        notes.append(f"{key} is not in it: today's default {toml_value(today[section][name])} applies "
                     f"(runs before it existed behaved as [{section}] {name} = {toml_value(before)})")
    return notes


def load_davio_config(path: str | Path, warn: Callable[[str], None] | None = None) -> DavioConfig:
    """Read a DAVIO configuration (TOML; e.g. a run's saved config.toml) into DavioConfig.

    Args:
        path: the TOML file.
        warn: called with one message when the file is a resolved config.toml saved before some of
            NEWER_OPTIONS existed (default: print it to stderr), so that a re-run that differs from the
            old run is never silent.

    Raises:
        ConfigError: the file is missing, not TOML, or holds an unknown option or a bad value.
    """
    data = read_toml(path)
    cfg = config_from_toml_dict(DavioConfig, data, path)
    notes = newer_option_notes(data)
    if notes:
        msg = (f"note: {path} was saved by an earlier DAVIO; options added since take today's defaults:\n  "
               + "\n  ".join(notes) + "\n  (set them in the file to reproduce the earlier run)")
        (warn or (lambda m: print(m, file=sys.stderr)))(msg)
    return cfg
