"""Dense depth error model of the emulated DA3: smooth fields, noise, flying pixels, artefacts.

All errors act on log depth, per view, in pixel coordinates of the rectified image (u right,
v down, (0, 0) at the centre of the top-left pixel). Inputs are the depth the model "believes"
(the true depth for the unconditioned call, the input-pose-consistent depth for the conditioned
one) and the true metric depth, which sets the far-range degradation.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from models.emulated_da3.params import EmulatorParams

#: Expected relative error floor used by the confidence when every error mode is switched off.
MIN_EXPECTED_REL_ERROR = 1e-4


@dataclass(frozen=True)
class DenseErrorLevels:
    """Effective 1-sigma levels of one call (uncond or cond, after the small-baseline rule).

    Attributes:
        image_log_scale: per-image log-scale sigma.
        field: smooth relative field sigma.
        noise: per-pixel relative noise sigma (up to d_far).
    """

    image_log_scale: float
    field: float
    noise: float


@dataclass
class CorruptedView:
    """One view after the error model.

    Attributes:
        depth: (H, W) float64 corrupted depth (finite, > 0), in the input depth's units.
        expected_error: (H, W) float64 expected absolute error (same units), drives confidence.
        flying: (H, W) bool, pixels turned into flying pixels.
        band: (H, W) bool, the discontinuity band.
        sky: (H, W) bool, pixels without a surface.
    """

    depth: np.ndarray
    expected_error: np.ndarray
    flying: np.ndarray
    band: np.ndarray
    sky: np.ndarray


def smooth_field(
    rng: np.random.Generator, height: int, width: int, n_modes: int, wavelength_frac: tuple[float, float]
) -> np.ndarray:
    """A smooth Gaussian random field with unit variance at every pixel, (H, W) float64.

    Sum of n_modes plane waves A cos(k.x) + B sin(k.x) with A, B ~ N(0, 1), divided by
    sqrt(n_modes); directions uniform, wavelengths log-uniform in wavelength_frac x diagonal.
    """
    diag = float(np.hypot(width, height))
    lam = diag * np.exp(rng.uniform(np.log(wavelength_frac[0]), np.log(wavelength_frac[1]), n_modes))
    ang = rng.uniform(0.0, 2.0 * np.pi, n_modes)
    kx, ky = 2.0 * np.pi / lam * np.cos(ang), 2.0 * np.pi / lam * np.sin(ang)
    a, b = rng.normal(size=n_modes), rng.normal(size=n_modes)
    u = np.arange(width, dtype=np.float64)
    v = np.arange(height, dtype=np.float64)
    # separable: A cos(a + b) + B sin(a + b) = (A cos b + B sin b) cos a + (B cos b - A sin b) sin a
    au, bv = u[None, :] * kx[:, None], v[:, None] * ky[None, :]  # (M, W), (H, M)
    cb, sb = np.cos(bv), np.sin(bv)
    out = (a * cb + b * sb) @ np.cos(au) + (b * cb - a * sb) @ np.sin(au)
    return out / np.sqrt(n_modes)


def flying_band(
    depth: np.ndarray, radius_px: int, jump_rel: float, surface_id: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Band of pixels within radius_px of a depth discontinuity, with local near/far depths.

    Inverse depth is affine in the pixel coordinates on a plane, so its second difference along a
    row or column vanishes on planes (however oblique) and equals (1 - d_near/d_far)/2 in units of
    the pixel's own inverse depth next to a step. A pixel is on a discontinuity when that relative
    second difference exceeds jump_rel/2 along the row or the column, i.e. a depth step of more
    than jump_rel, or (with surface_id) when a 4-neighbour on another surface differs by more than
    jump_rel in log depth (catches steps spread over a grazing one-pixel face). Returns (band
    (H,W) bool, near (H,W), far (H,W)) where near/far are the min/max depth over the (2r+1)^2
    neighbourhood.
    """
    inv = 1.0 / depth
    pad = np.pad(inv, 1, mode="reflect", reflect_type="odd")  # linear extrapolation: no border edges
    c = pad[1:-1, 1:-1]
    d2x = np.abs(2.0 * c - pad[1:-1, :-2] - pad[1:-1, 2:])
    d2y = np.abs(2.0 * c - pad[:-2, 1:-1] - pad[2:, 1:-1])
    edge = np.maximum(d2x, d2y) > jump_rel * c  # (2c - a - b) / (2c) > jump_rel / 2
    if surface_id is not None:
        logd = np.log(depth)
        for ax in (0, 1):
            a = [slice(None), slice(None)]
            b = [slice(None), slice(None)]
            a[ax], b[ax] = slice(1, None), slice(None, -1)
            step = (np.abs(logd[tuple(a)] - logd[tuple(b)]) > jump_rel) & (
                surface_id[tuple(a)] != surface_id[tuple(b)]
            )
            edge[tuple(a)] |= step
            edge[tuple(b)] |= step
    r = max(int(radius_px), 1)
    band = edge
    if r > 1:
        band = cv2.dilate(edge.astype(np.uint8), np.ones((2 * r - 1, 2 * r - 1), np.uint8)).astype(bool)
    d32 = depth.astype(np.float32)
    kr = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    near = cv2.erode(d32, kr).astype(np.float64)
    far = cv2.dilate(d32, kr).astype(np.float64)
    return band, near, far


def band_radius_px(width: int, params: EmulatorParams) -> int:
    """Half-width (pixels, >= 1) of the flying-pixel band at this image width."""
    return max(1, int(round(params.flying_band_px_at_504 * width / 504.0)))


def corrupt_view(
    rng: np.random.Generator,
    depth_model: np.ndarray,
    depth_true: np.ndarray,
    texture: np.ndarray,
    reflective: np.ndarray,
    dynamic: np.ndarray,
    surface_id: np.ndarray,
    params: EmulatorParams,
    levels: DenseErrorLevels,
    d_far: float,
) -> CorruptedView:
    """Apply every dense error mode to one view.

    Args:
        rng: the call's generator.
        depth_model: (H, W) depth the model believes before errors (any units; inf = no surface).
        depth_true: (H, W) true metric z-depth (m; inf = no surface): sets the far-range ratio.
        texture, reflective, dynamic, surface_id: (H, W) ground-truth attributes.
        params: the error model.
        levels: this call's sigmas.
        d_far: start of the far range (m).
    """
    H, W = depth_model.shape
    sky = ~np.isfinite(depth_model)
    finite = depth_model[~sky]
    d_sky = params.sky_depth_factor * (float(finite.max()) if finite.size else d_far)
    d = np.where(sky, d_sky, depth_model).astype(np.float64)
    d_ref = d.copy()

    # reflective surfaces: with reflective_prob, the surface shows a mirror image behind itself
    refl = np.asarray(reflective, bool) & ~sky
    for sid in np.unique(surface_id[refl]):
        if rng.random() < params.reflective_prob:
            m = refl & (surface_id == sid)
            d[m] *= rng.uniform(*params.reflective_depth_gain_range)

    # flying pixels: a share of the discontinuity band blends the near and far side
    band, near, far = flying_band(d, band_radius_px(W, params), params.flying_jump_rel, surface_id)
    flying = band & (rng.random((H, W)) < params.flying_fraction)
    alpha = rng.random((H, W))
    d = np.where(flying, near + alpha * (far - near), d)

    # gains: far range (true metric depth), low texture, moving objects
    d_metric = np.where(np.isfinite(depth_true), depth_true, np.inf)
    q = np.maximum(1.0, np.where(np.isfinite(d_metric), d_metric, 0.0) / d_far)
    q = np.where(sky, np.maximum(q, params.sky_depth_factor), q)
    thr = params.low_texture_threshold
    w_tex = np.clip(1.0 - np.asarray(texture, np.float64) / thr, 0.0, 1.0) if thr > 0 else np.zeros((H, W))
    s_field = levels.field * (1.0 + (params.low_texture_field_gain - 1.0) * w_tex) * np.sqrt(q)
    s_noise = levels.noise * (1.0 + (params.low_texture_noise_gain - 1.0) * w_tex) * q
    s_noise = s_noise * np.where(np.asarray(dynamic, bool), params.dynamic_noise_gain, 1.0)

    image_log_scale = rng.normal(0.0, levels.image_log_scale) if levels.image_log_scale > 0 else 0.0
    log_err = np.zeros((H, W))
    if levels.field > 0:
        log_err += s_field * smooth_field(rng, H, W, params.field_modes, params.field_wavelength_frac)
    if levels.noise > 0:
        log_err += s_noise * rng.normal(size=(H, W))
    local = d * np.exp(log_err)  # every error the image itself can reveal (not the image's scale)
    out = local * np.exp(image_log_scale)

    # expected absolute error: a-priori (conditions) blended with the error actually made
    rel = np.maximum(np.sqrt(s_field**2 + s_noise**2), MIN_EXPECTED_REL_ERROR)
    prior = d * rel * np.where(band, params.edge_conf_factor, 1.0)
    prior = prior * np.where(refl, params.reflective_conf_factor, 1.0)
    kappa = params.conf_error_awareness
    actual = np.abs(local - d_ref) + 0.1 * prior
    expected = prior ** (1.0 - kappa) * actual**kappa
    expected = np.where(sky, d_sky, expected)
    return CorruptedView(out, expected, flying, band, sky)


def confidence(rng: np.random.Generator, expected_error: np.ndarray, params: EmulatorParams) -> np.ndarray:
    """DA3-like confidence (>= 1) for all views of a call: inverse expected error with jitter.

    conf = 1 + K_call * (median(e) / e) * exp(N(0, conf_log_jitter)), with
    K_call = conf_level_median * exp(N(0, conf_level_log_sigma)), so levels differ between calls.
    """
    e = np.maximum(expected_error, np.finfo(np.float64).tiny)
    level = params.conf_level_median * np.exp(rng.normal(0.0, params.conf_level_log_sigma))
    jitter = np.exp(params.conf_log_jitter * rng.normal(size=e.shape))
    return (1.0 + level * (np.median(e) / e) * jitter).astype(np.float32)
