"""The mapper variants of `davio bench mapping` and how one is run on a sequence's windows.

  a  DAVIO: the conditioned mapper on the VIO poses
  b  unconditioned reference: the same mapper, DA3 called without poses (`Mapper(conditioned=False)`)
  c  ScaRF-style mapper (tools/benchmarks/scarf_mapper.py) on the VIO poses and the conditioned call
  d  DAVIO on the true camera poses (no trajectory alignment needed)
  e  DAVIO without the emulator's conditioning benefit: the conditioned call with the conditioned
     dense-error levels set to the unconditioned ones (image_log_scale_sigma_cond =
     image_log_scale_sigma, field_sigma_cond = field_sigma; the per-pixel noise is shared anyway)
  f  sensitivity: DAVIO with the dense depth errors doubled (per-image log-scale, smooth field and
     per-pixel noise, conditioned and unconditioned)
  g  DAVIO with the submap graph off (submaps placed with the filter's poses, lambda = 0)
  h  unconditioned reference with the emulator's upper-bound pose errors (`<size>_upper`): the
     reference's window scale comes from DA3's predicted cameras, which the default emulator
     makes nearly exact (PRESETS.md)
  i  diagnosis: DAVIO on windows whose centre camera keeps its VIO pose but whose other images sit at
     their TRUE poses relative to it (`relative_truth_windows`): what the filter's pose error within a
     window costs the map, apart from the error of where the window sits
Every variant gets a fresh emulated DA3 with the same seed and the same windows (frames and poses).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from runtime.mapping.config import MappingConfig

DENSE_ERROR_FIELDS: tuple[str, ...] = (
    "image_log_scale_sigma", "image_log_scale_sigma_cond", "field_sigma", "field_sigma_cond", "noise_sigma")
"""The emulator's dense depth-error sigmas (models/emulated_da3/params.py), doubled by variant f."""


@dataclass(frozen=True)
class Variant:
    """One row of the benchmark.

    Attributes:
        key: "a".."f"; label: the row's name.
        mapper: "davio" (runtime.mapping.Mapper) or "scarf" (the ScaRF-style baseline).
        poses: "vio" (aligned to the truth for evaluation), "gt" (true camera poses) or "vio_centre"
            (VIO centre poses, true poses within each window; aligned like "vio").
        conditioned: the DA3 call is conditioned on the poses (DAVIO's mapper only).
        errors: "default", "no_cond_benefit", "depth_x2" (emulated-DA3 overrides) or "upper_pose"
            (the `<size>_upper` preset).
        graph: DAVIO's submap graph on (off: T_MS = T_OS, lambda = 0).
        keep_unseen: DAVIO keeps depths no other image of the window sees (off: the paper's rule).
    """

    key: str
    label: str
    mapper: str = "davio"
    poses: str = "vio"
    conditioned: bool = True
    errors: str = "default"
    graph: bool = True
    keep_unseen: bool = True


VARIANTS: tuple[Variant, ...] = (
    Variant("a", "DAVIO"),
    Variant("b", "unconditioned reference", conditioned=False),
    Variant("c", "ScaRF-style", mapper="scarf"),
    Variant("d", "DAVIO, true poses", poses="gt"),
    Variant("e", "DAVIO, no conditioning benefit", errors="no_cond_benefit"),
    Variant("f", "DAVIO, depth errors x2", errors="depth_x2"),
    Variant("g", "DAVIO, graph off", graph=False),
    Variant("h", "unconditioned, upper-bound pose errors", conditioned=False, errors="upper_pose"),
    Variant("i", "DAVIO, true poses within windows", poses="vio_centre"),
    Variant("j", "DAVIO, paper's strict multi-view rule", keep_unseen=False),
)
VARIANT_KEYS = "".join(v.key for v in VARIANTS)


def depth_error_overrides(preset: str, factor: float) -> dict[str, float]:
    """The emulated-DA3 overrides multiplying every dense depth-error sigma of `preset` by `factor`."""
    from models.emulated_da3 import make_params

    p = make_params(preset)
    return {} if factor == 1.0 else {name: factor * getattr(p, name) for name in DENSE_ERROR_FIELDS}


def emulator_overrides(errors: str, preset: str) -> dict[str, float]:
    """The emulated-DA3 parameter overrides of an error setting on top of `preset`."""
    from models.emulated_da3 import make_params

    p = make_params(preset)
    if errors in ("default", "upper_pose"):
        return {}
    if errors == "no_cond_benefit":
        return {"image_log_scale_sigma_cond": p.image_log_scale_sigma, "field_sigma_cond": p.field_sigma}
    if errors == "depth_x2":
        return depth_error_overrides(preset, 2.0)
    raise ValueError(f"unknown error setting {errors!r}")


@dataclass
class VariantRun:
    """A variant's map (in its poses' frame) and counters.

    Attributes:
        points: (P,3) the exported cloud (DAVIO: every submap fused into 4 cm voxels; ScaRF: every
            exported point).
        offered, accepted: windows given to the mapper and windows it mapped.
        rejected: refusals by reason (DAVIO's gates; model errors).
        seconds: wall time of the mapping.
        overrides: emulated-DA3 overrides used.
    """

    points: np.ndarray
    offered: int
    accepted: int
    rejected: dict = field(default_factory=dict)
    seconds: float = 0.0
    overrides: dict = field(default_factory=dict)
    submaps: list = field(default_factory=list)
    """DAVIO's committed submaps at their final graph states (empty for ScaRF)."""


def relative_truth_windows(inputs: Any) -> list:
    """The VIO windows with each image moved to its true pose relative to the window's centre image:
    T_OC_i = T_OC_c (T_WC_c^-1 T_WC_i) (odometry frame, so the map is aligned like the VIO map)."""
    from runtime.mapping.windows import MappingWindow

    out = []
    for w, wg in zip(inputs.windows, inputs.windows_gt, strict=True):
        c = len(w.T_OC) // 2
        T_gt = np.asarray(wg.T_OC, np.float64)
        rel = np.linalg.inv(T_gt[c]) @ T_gt
        out.append(MappingWindow(w.window_id, w.frames, np.asarray(w.T_OC, np.float64)[c] @ rel, w.segment))
    return out


def keep_submaps(commit: Any, by_index: dict[int, Any]) -> None:
    """Record a commit's new submap in `by_index` (index -> Submap) and carry the new graph states it
    reports for submaps that left the mapper's memory over to their Submap objects, so that
    `by_index` ends with every submap at its final state (as the archive's manifest does)."""
    by_index[commit.submap.index] = commit.submap
    for ch in commit.changed:
        sm = by_index[ch.index]
        if sm is not ch:
            sm.T_MS, sm.lam, sm.version = ch.T_MS, ch.lam, ch.version


def export_points(submaps: list, voxel_m: float) -> np.ndarray:
    """(V,3) the final map of DAVIO's mapper: every committed submap fused into voxels at its current
    state (as the run's final export re-fuses every archive; the live grid keeps only the resident
    submaps)."""
    from runtime.mapping.fusion import VoxelGrid

    grid = VoxelGrid(voxel_m)
    for sub in submaps:
        grid.integrate(sub.points_M(), sub.grey)
    return grid.points()[0]


def run_variant(variant: Variant, inputs: Any, truth: Any, camera: Any, mapping: MappingConfig,
                preset: str, seed: int, matcher: Any, graph: Any = None) -> VariantRun:
    """Map the sequence's windows with one variant (a fresh emulated DA3 seeded with `seed`).

    Args:
        inputs: tools.benchmarks.mapping_inputs.MappingInputs.
        truth: the ground-truth source for the emulated DA3 (e.g. a CachedTruth).
        camera: the rig's camera model (width, height, K: the rectified view of the emulator).
        matcher: the matcher for DAVIO's per-frame scales (shared by the variants).
        graph: the submap graph's GraphConfig for the variants that use the graph (None: the default).
    """
    from models.emulated_da3 import EmulatedDA3
    from runtime.mapping.mapper import MapCommit, Mapper
    from tools.benchmarks.scarf_mapper import ScarfConfig, ScarfMapper

    overrides = emulator_overrides(variant.errors, preset)
    da3 = f"{preset.removesuffix('_upper')}_upper" if variant.errors == "upper_pose" else preset
    model = EmulatedDA3(truth, camera.K, camera.width, camera.height, preset=da3, seed=seed, **overrides)
    windows = {"gt": inputs.windows_gt, "vio_centre": None}.get(variant.poses, inputs.windows)
    if variant.poses == "vio_centre":
        windows = relative_truth_windows(inputs)
    t0 = time.perf_counter()
    if variant.mapper == "scarf":
        scfg = ScarfConfig(pixel_stride=mapping.pixel_stride, max_depth_m=mapping.max_depth_m)
        sm = ScarfMapper(model, scfg)
        for w in windows:
            sm.process(w)
        points = sm.points()[0]
        rejected = {"model_error": len(sm.stats.model_errors)} if sm.stats.model_errors else {}
        return VariantRun(points, len(windows), sm.stats.windows_accepted, rejected,
                          time.perf_counter() - t0, overrides)
    if not variant.keep_unseen:
        mapping = replace(mapping, multiview_keep_unseen=False)
    m = Mapper(model, camera, mapping, matcher=matcher, conditioned=variant.conditioned,
               graph=graph if variant.graph else False)
    by_index: dict[int, Any] = {}
    for w in windows:
        m.stats.windows_offered += 1
        out = m.process(w)
        if isinstance(out, MapCommit):
            keep_submaps(out, by_index)
    points = export_points(list(by_index.values()), mapping.voxel_m)
    return VariantRun(points, m.stats.windows_offered, m.stats.windows_accepted,
                      dict(m.stats.windows_rejected), time.perf_counter() - t0, overrides,
                      [by_index[k] for k in sorted(by_index)])
