"""Emulated Depth Anything 3 for simulated recordings (DESIGN §4 "Emulated DA3", PRESETS.md).

`EmulatedDA3` implements the `DepthModel` protocol of the ONNX backend from simulator ground truth
plus DA3's failure modes, each a named `EmulatorParams` field, with Small/Base/Large presets.
"""

from __future__ import annotations

from models.emulated_da3.analytic import BoxRoom
from models.emulated_da3.emulator import BACKEND, EmulatedDA3
from models.emulated_da3.groundtruth import GroundTruthSource, GroundTruthView
from models.emulated_da3.params import PRESETS, EmulatorParams, make_params

__all__ = [
    "BACKEND",
    "BoxRoom",
    "EmulatedDA3",
    "EmulatorParams",
    "GroundTruthSource",
    "GroundTruthView",
    "PRESETS",
    "make_params",
]
