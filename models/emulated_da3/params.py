"""Error-model parameters of the emulated DA3 and the Small/Base/Large presets.

Every failure mode of DESIGN §4 is one named field below; `PRESETS.md` next to this file explains
how each default was chosen from notes/da3_accuracy.md §4. All sigmas are 1-sigma values of
natural-log quantities unless the name says otherwise (``_deg`` = degrees, ``_m`` = metres,
``_frac`` = fraction). "uncond" = the start-up call without poses, "cond" = the pose-conditioned
mapping call.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from runtime.errors import ConfigError


@dataclass(frozen=True)
class EmulatorParams:
    """Parameters of the emulated DA3 error model (see PRESETS.md for the chosen values).

    Scale (up-to-scale output and scale inconsistencies):
        global_log_scale_sigma: uncond: after normalising the window so that the mean camera-0
            point distance is 1, the whole output (depth and translations) is multiplied by
            exp(N(0, this)): the random global scale per call.
        image_log_scale_sigma: uncond: per-image log-scale inconsistency (each depth map times
            exp(N(0, this))).
        image_log_scale_sigma_cond: cond: the same, when conditioned on poses.
        window_log_scale_sigma_cond: cond: residual log-scale of the returned metric depth of a
            whole window (what the mapper's per-submap lambda absorbs).
        window_outlier_prob: cond: probability that a window is a conditioning failure whose
            predicted camera scale is off by exp(+-U(window_outlier_range)); the wrapper divides
            the depth by that wrong scale, and the reported scale shows it (|log| > 0.3 gate).
        window_outlier_range: cond: (min, max) |log| of that camera-scale outlier.
        mono_log_scale_sigma: cond: when the true camera centres do not move (< 1 mm spread) the
            images carry no metric cue; depth scale is then off by exp(N(0, this)).

    Dense depth errors (all multiplicative, in log depth):
        field_sigma: uncond: std of the smooth relative depth error field (a Gaussian random
            field of `field_modes` plane waves; every pixel's marginal is N(0, field_sigma^2)).
        field_sigma_cond: cond: the same, conditioned.
        field_modes: number of plane waves in the field.
        field_wavelength_frac: (min, max) wavelength of the waves, fraction of the image diagonal
            (log-uniform): the field is smooth over the image.
        noise_sigma: per-pixel iid relative depth noise (fraction of depth) up to `d_far`; the
            absolute noise therefore grows linearly with depth, and faster beyond d_far.
        far_baseline_factor, far_min_m, far_max_m: far range starts at
            d_far = clip(far_baseline_factor * median consecutive true baseline, far_min_m,
            far_max_m). Beyond it noise x (d/d_far), field x sqrt(d/d_far), and the expected
            error used by the confidence grows accordingly.
        sky_depth_factor: pixels without a surface (sky, no hit) get this factor times the
            largest finite depth of the view (DA3 has no sky head) and the lowest confidence.

    Artefacts:
        flying_band_px_at_504: half-width of the band around depth discontinuities, in pixels of
            a 504-px-wide image (scaled to the camera width, at least 1 px).
        flying_jump_rel: a relative depth step larger than this between neighbouring pixels is a
            discontinuity (found on the second difference of inverse depth, so oblique planes
            never count).
        flying_fraction: share of band pixels that become flying pixels (depth blended
            uniformly between the near and far side).
        low_texture_threshold: texture strength (0..1) below which a pixel counts as low-texture,
            with weight w = clip(1 - texture / threshold, 0, 1).
        low_texture_field_gain, low_texture_noise_gain: field and noise are multiplied by
            1 + (gain - 1) * w.
        reflective_prob: probability that a reflective surface (one surface_id) shows the mirror
            image, i.e. a depth behind the surface.
        reflective_depth_gain_range: (min, max) factor of that behind-the-mirror depth.
        dynamic_noise_gain: noise factor on moving pixels (DA3 assumes a static scene).
        dynamic_pose_gain: uncond pose errors are multiplied by 1 + this * dynamic pixel fraction.

    Confidence (inverse expected error, only comparable within a call):
        conf_level_median: median of the per-call confidence level K_call.
        conf_level_log_sigma: K_call = conf_level_median * exp(N(0, this)).
        conf_log_jitter: conf = 1 + K_call * (median(e) / e) * exp(N(0, this)) with e the expected
            absolute error of the pixel.
        conf_error_awareness: kappa in [0, 1]: e = prior^(1 - kappa) * (|local error| + 0.1 prior)^kappa,
            where prior is the error expected from the conditions (depth, far range, texture, edge
            band, mirrors) and the local error the one actually made in this pixel by the field,
            noise, flying pixels and mirrors (not the image's or window's scale, which a single
            image cannot reveal). DA3's confidence head is trained to predict its own error
            (notes/da3_accuracy.md §2); kappa sets how well it succeeds.
        edge_conf_factor: expected-error factor of the discontinuity band.
        reflective_conf_factor: expected-error factor of reflective pixels.

    Unconditioned poses and intrinsics (world = camera 0):
        rotation_error_median_deg, rotation_error_frac: the relative-rotation error angle is
            lognormal with median rotation_error_median_deg + rotation_error_frac * true angle,
            about a uniformly random axis.
        rotation_error_log_sigma: log-spread of that lognormal.
        translation_direction_median_deg, translation_direction_log_sigma: the direction of the
            camera centre seen from camera 0 is rotated by a lognormal angle (median, log-spread)
            about a random perpendicular axis.
        translation_norm_log_sigma: its length is multiplied by exp(N(0, this)).
        centre_floor_frac: then isotropic N(0, (this * median true depth)^2) is added to each
            camera centre (per axis): the absolute camera-centre floor.
        focal_log_sigma: predicted fx, fy = true * exp(N(0, this)) per view (one factor for both);
            the principal point is the rectified camera's.

    Conditioned call:
        cond_image_weight: beta in [0, 1]: the model's cameras follow the input poses, pulled by
            beta towards the camera the images show (the truth after the similarity that best maps
            true onto input cameras). Depth is computed from those cameras, so an input pose error
            passes into the depth by (1 - beta) and shows in the centre-fit RMSE by beta.
        cond_centre_noise_frac: std of the model's camera-centre noise per axis, as a fraction of
            DA3's pose normalisation distance (the lower-median camera distance to view 0).
        small_baseline_m, small_baseline_gain_factor: below this median consecutive baseline the
            conditioning gain (uncond error / cond error) is reduced by this factor (errors move
            halfway back to the unconditioned ones for 0.5).
    """

    global_log_scale_sigma: float = 0.1
    image_log_scale_sigma: float = 0.04
    image_log_scale_sigma_cond: float = 0.017
    window_log_scale_sigma_cond: float = 0.03
    window_outlier_prob: float = 0.02
    window_outlier_range: tuple[float, float] = (0.3, 0.7)
    mono_log_scale_sigma: float = 0.3

    field_sigma: float = 0.021
    field_sigma_cond: float = 0.014
    field_modes: int = 12
    field_wavelength_frac: tuple[float, float] = (0.5, 2.0)
    noise_sigma: float = 0.014
    far_baseline_factor: float = 20.0
    far_min_m: float = 3.0
    far_max_m: float = 50.0
    sky_depth_factor: float = 2.0

    flying_band_px_at_504: float = 2.0
    flying_jump_rel: float = 0.03
    flying_fraction: float = 0.6
    low_texture_threshold: float = 0.05
    low_texture_field_gain: float = 2.0
    low_texture_noise_gain: float = 1.5
    reflective_prob: float = 0.5
    reflective_depth_gain_range: tuple[float, float] = (1.3, 2.0)
    dynamic_noise_gain: float = 2.0
    dynamic_pose_gain: float = 5.0

    conf_level_median: float = 5.0
    conf_level_log_sigma: float = 0.3
    conf_log_jitter: float = 0.4
    conf_error_awareness: float = 0.5
    edge_conf_factor: float = 6.0
    reflective_conf_factor: float = 2.0

    # Base = POSE_ERROR_SCALE x the upper bound POSE_ERRORS_UPPER["base"] (PRESETS.md)
    rotation_error_median_deg: float = 0.03
    rotation_error_frac: float = 0.001
    rotation_error_log_sigma: float = 0.6
    translation_direction_median_deg: float = 0.195
    translation_direction_log_sigma: float = 0.9
    translation_norm_log_sigma: float = 0.002
    centre_floor_frac: float = 0.000075
    focal_log_sigma: float = 0.03

    cond_image_weight: float = 0.3
    cond_centre_noise_frac: float = 0.01
    small_baseline_m: float = 0.1
    small_baseline_gain_factor: float = 0.5

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            vals = v if isinstance(v, tuple) else (v,)
            for x in vals:
                if not isinstance(x, (int, float)) or x != x or x < 0:
                    raise ConfigError(
                        f"emulated DA3 parameter {f.name} must be a finite number >= 0, got {v!r}"
                    )
            if isinstance(v, tuple) and (len(v) != 2 or v[0] > v[1]):
                raise ConfigError(f"emulated DA3 parameter {f.name} must be a (min, max) pair, got {v!r}")
        for name in (
            "window_outlier_prob",
            "flying_fraction",
            "reflective_prob",
            "cond_image_weight",
            "small_baseline_gain_factor",
        ):
            if getattr(self, name) > 1.0:
                raise ConfigError(
                    f"emulated DA3 parameter {name} is a probability/weight in [0, 1], "
                    f"got {getattr(self, name)}"
                )
        if self.field_modes < 1 or self.field_wavelength_frac[0] <= 0:
            raise ConfigError("emulated DA3 field needs field_modes >= 1 and positive wavelengths")
        if self.far_min_m <= 0 or self.far_min_m > self.far_max_m:
            raise ConfigError(
                f"emulated DA3 needs 0 < far_min_m <= far_max_m, got {self.far_min_m}, {self.far_max_m}"
            )
        if self.conf_level_median <= 0 or self.sky_depth_factor < 1.0:
            raise ConfigError("emulated DA3 needs conf_level_median > 0 and sky_depth_factor >= 1")


#: Per-preset values (everything not listed takes the `EmulatorParams` default, which is Base); the
#: unconditioned pose errors come from POSE_ERRORS_UPPER x POSE_ERROR_SCALE (below).
_PRESET_VALUES: dict[str, dict[str, float]] = {
    "small": dict(
        image_log_scale_sigma=0.06,
        image_log_scale_sigma_cond=0.025,
        window_log_scale_sigma_cond=0.045,
        window_outlier_prob=0.02,
        field_sigma=0.030,
        field_sigma_cond=0.020,
        noise_sigma=0.020,
        flying_fraction=0.7,
        focal_log_sigma=0.05,
    ),
    "base": dict(),
    "large": dict(
        image_log_scale_sigma=0.03,
        image_log_scale_sigma_cond=0.012,
        window_log_scale_sigma_cond=0.02,
        window_outlier_prob=0.01,
        field_sigma=0.015,
        field_sigma_cond=0.010,
        noise_sigma=0.010,
        flying_fraction=0.5,
        focal_log_sigma=0.02,
    ),
}

POSE_ERROR_FIELDS: tuple[str, ...] = (
    "rotation_error_median_deg",
    "rotation_error_frac",
    "translation_direction_median_deg",
    "translation_norm_log_sigma",
    "centre_floor_frac",
)
"""The unconditioned pose-error knobs, scaled together by `scale_pose_errors`."""


def scale_pose_errors(params: EmulatorParams, k: float) -> EmulatorParams:
    """`params` with every unconditioned pose-error knob (POSE_ERROR_FIELDS) multiplied by k >= 0."""
    if not k >= 0:
        raise ConfigError(f"pose-error factor must be >= 0, got {k}")
    return replace(params, **{name: getattr(params, name) * k for name in POSE_ERROR_FIELDS})


#: Upper-bound unconditioned pose errors per model size (PRESETS.md): the AUC-derived translation
#: directions of DA3 Table 2 (scene-wide sets of up to 100 frames) and the note's rotation, length
#: and floor values. The `<size>_upper` presets use them.
POSE_ERRORS_UPPER: dict[str, dict[str, float]] = {
    "small": dict(rotation_error_median_deg=1.0, rotation_error_frac=0.03,
                  translation_direction_median_deg=6.0, translation_norm_log_sigma=0.06,
                  centre_floor_frac=0.0025),
    "base": dict(rotation_error_median_deg=0.6, rotation_error_frac=0.02,
                 translation_direction_median_deg=3.9, translation_norm_log_sigma=0.04,
                 centre_floor_frac=0.0015),
    "large": dict(rotation_error_median_deg=0.3, rotation_error_frac=0.01,
                  translation_direction_median_deg=1.4, translation_norm_log_sigma=0.03,
                  centre_floor_frac=0.001),
}

POSE_ERROR_SCALE = 0.05
"""[M] The factor on POSE_ERRORS_UPPER that makes the feed-forward initializer alone reproduce the
paper's start-up accuracy (median velocity 0.07 m/s, gravity 1 deg) on EuRoC-trajectory recordings:
`davio bench ffinit-accuracy` (PRESETS.md, "Calibrating the unconditioned pose errors")."""

_UPPER = {name: EmulatorParams(**{**values, **POSE_ERRORS_UPPER[name]})
          for name, values in _PRESET_VALUES.items()}
PRESETS: dict[str, EmulatorParams] = {name: scale_pose_errors(p, POSE_ERROR_SCALE)
                                      for name, p in _UPPER.items()}
PRESETS.update({f"{name}_upper": p for name, p in _UPPER.items()})
"""The presets standing in for DA3 Small, Base and Large (PRESETS.md): `small`, `base`, `large` with
the calibrated pose errors, and `<size>_upper` with the upper-bound ones (otherwise identical)."""


def make_params(preset: str = "base", **overrides: object) -> EmulatorParams:
    """The parameters of `preset` with named fields overridden.

    Raises:
        ConfigError: unknown preset, unknown field name, or an invalid value.
    """
    if preset not in PRESETS:
        raise ConfigError(f"unknown emulated DA3 preset {preset!r}; choose one of {sorted(PRESETS)}")
    names = {f.name for f in fields(EmulatorParams)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ConfigError(f"unknown emulated DA3 parameter(s) {unknown}; valid names: {sorted(names)}")
    clean = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    return replace(PRESETS[preset], **clean)
