"""Feed-forward point–inertial initializer (paper Sec. IV): DA3 window + preintegrated IMU ->
metric scale, velocity and gravity, with conditioning gates, stratified LMedS and refinement."""
from __future__ import annotations

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.linear import LinearSolution, solve_linear
from runtime.ffinit.robust import RobustResult, robust_solve
from runtime.ffinit.window import ImageObservations, InitWindow, Rejection

__all__ = [
    "FFInitConfig",
    "ImageObservations",
    "InitWindow",
    "LinearSolution",
    "Rejection",
    "RobustResult",
    "robust_solve",
    "solve_linear",
]
