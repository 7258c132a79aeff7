"""The one configuration of a DAVIO run: nested dataclasses whose defaults are the paper's (and
OpenVINS EuRoC's) numbers, loadable from and saved to a single TOML file (runtime.config_io)."""
from __future__ import annotations

from dataclasses import dataclass, field

from runtime.ffinit.config import FFInitConfig
from runtime.graph.config import GraphConfig
from runtime.graph.revisits import RevisitConfig
from runtime.mapping.config import MappingConfig
from runtime.msckf.config import MsckfConfig
from runtime.msckf.init_dynamic import DynamicInitConfig
from runtime.msckf.init_static import StaticInitConfig
from runtime.msckf.tracker import TrackerConfig
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
