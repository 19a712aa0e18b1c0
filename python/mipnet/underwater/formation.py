"""Synthetic underwater degradation of an in-air stereo pair (photometric only).

Model (Akkaynak-Treibitz revised image formation, per colour channel c, linear RGB, range z in m):

    I_c = gain * [ blur_z( J_c * E_c * exp(-beta^D_c z) ) + B_c * (1 - exp(-beta^B_c z)) ] + noise

* ``beta^D = K_d(water_type) + scattering`` with Jerlov's diffuse attenuation K_d (R = 650 nm,
  G = 550 nm, B = 450 nm) plus a spectrally flat scattering term; ``beta^B`` is its own
  per-channel coefficient;
* ``E_c = exp(-K_d,c * d_v) + artificial light``: sunlight dimmed over the vertical depth d_v of
  the scene point (camera depth plus the point's height below the camera), plus an optional spot
  light at the camera (inverse-square falloff, attenuated on its way out);
* ``B_c``: veiling light, dimmed by ``exp(-K_d,c * depth)``;
* ``blur_z``: forward scatter, a Gaussian blur whose sigma grows linearly with range (a per-pixel
  blend of a few blur levels);
* auto-exposure from the left view's luminance (shared by both cameras), then ``gain`` (low light), marine
  snow (particles at 0.3-3 m drawn at consistent positions in both views), and Poisson-Gaussian
  sensor noise drawn independently per view.

Range comes from the left disparity with a ZED-like default calibration (``fx = 700 px`` at
1280 px width, scaled with the image width; baseline 0.12 m), clipped to ``[z_min, z_max]``;
pixels with invalid disparity (non-finite or <= 0) are placed at ``z_max``. The right view's range
is the left range forward-warped with the disparity, holes filled with the farther neighbour
(occluded background). The disparity itself is not changed.
"""

from __future__ import annotations

import numpy as np

from ..errors import ArgumentError, ShapeError
from ..stereo.filters import box_sum, gaussian_blur
from .color import linear_to_srgb, srgb_to_linear
from .water import JERLOV_KD, REFERENCE_WIDTH, WaterParams, resolve_params

__all__ = ["degrade", "texture_snr", "direct_signal"]

_EXPOSURE_MEAN = 0.2  # auto-exposure: mean linear luminance target (sRGB ~124) ...
_EXPOSURE_HIGHLIGHT = 0.9  # ... unless that pushes the 99th percentile above this
_LUMINANCE = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)  # Rec. 709 weights of linear RGB
_SPOT_REFERENCE_RANGE = 0.5
_SNOW_RANGE = (0.3, 3.0)


# ---------------------------------------------------------------------------------- geometry


def _depth_from_disparity(disp: np.ndarray, fx: float, params: WaterParams) -> np.ndarray:
    """Depth (m) per pixel; invalid disparity -> z_max."""
    d = np.asarray(disp, dtype=np.float64)
    usable = np.isfinite(d) & (d > 0)
    depth = np.full(d.shape, params.z_max)
    np.divide(fx * params.baseline, d, out=depth, where=usable)
    return np.clip(depth, params.z_min, params.z_max)


def _warp_depth_to_right(depth: np.ndarray, disp: np.ndarray) -> np.ndarray:
    """Forward-warp left depth into the right view (nearest wins), holes take the farther neighbour.

    Each left pixel lands on the two right pixels around ``x - d``, so a surface stretched by up
    to 2x in the right view leaves no gaps for the background to show through.
    """
    height, width = depth.shape
    d = np.where(np.isfinite(disp) & (disp > 0), disp, 0.0)
    rows, cols = np.indices((height, width))
    right = np.full(height * width, np.inf)
    floor = np.floor(cols - d).astype(np.int64)
    for xr in (floor, floor + 1):
        inside = (xr >= 0) & (xr < width)
        np.minimum.at(right, (rows * width + xr)[inside], depth[inside])
    right = right.reshape(height, width)
    return _fill_holes_far(right, depth.max())


def _fill_holes_far(values: np.ndarray, default: float) -> np.ndarray:
    """Replace inf entries by the larger of the nearest finite values to their left and right."""
    height, width = values.shape
    have = np.isfinite(values)
    columns = np.arange(width)[None, :]
    # Index of the nearest finite entry at or before / at or after each column (-1 / width: none).
    before = np.maximum.accumulate(np.where(have, columns, -1), axis=1)
    after = np.minimum.accumulate(np.where(have, columns, width)[:, ::-1], axis=1)[:, ::-1]
    from_before = np.where(before >= 0, np.take_along_axis(values, np.clip(before, 0, width - 1), 1), -np.inf)
    from_after = np.where(after < width, np.take_along_axis(values, np.clip(after, 0, width - 1), 1), -np.inf)
    filled = np.maximum(from_before, from_after)
    filled = np.where(np.isfinite(filled), filled, default)
    return np.where(have, values, filled)


def _view_geometry(depth: np.ndarray, fx: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Line-of-sight range, height below the camera (m, down positive) and normalised radius."""
    height, width = depth.shape
    v, u = np.indices((height, width), dtype=np.float64)
    du = (u - (width - 1) / 2) / fx
    dv = (v - (height - 1) / 2) / fx
    ray_length = np.sqrt(1.0 + du**2 + dv**2)
    radius = np.hypot(u - (width - 1) / 2, v - (height - 1) / 2) / np.hypot(width, height)
    return depth * ray_length, depth * dv, radius


# ----------------------------------------------------------------------------------- blurring


def _range_blur(image: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Blur whose sigma varies per pixel: linear blend between the two nearest of a few blur levels."""
    top = float(sigma.max())
    if top <= 0:
        return image
    levels = [0.0]
    while levels[-1] < top:
        levels.append(max(1.0, 2.0 * levels[-1]))
    blurred = [image]
    for previous, current in zip(levels[:-1], levels[1:]):
        # Blurring by sqrt(current^2 - previous^2) turns level sigma `previous` into `current`.
        blurred.append(gaussian_blur(blurred[-1], float(np.sqrt(current**2 - previous**2))))
    out = np.zeros_like(image)
    for lower, upper, low_img, high_img in zip(levels[:-1], levels[1:], blurred[:-1], blurred[1:]):
        t = np.clip((sigma - lower) / (upper - lower), 0.0, 1.0)
        inside = (sigma >= lower) & ((sigma < upper) | (upper == levels[-1]))
        mix = (1.0 - t)[..., None] * low_img + t[..., None] * high_img
        out = np.where(inside[..., None], mix, out)
    return out


# ------------------------------------------------------------------------- image formation


def _illumination(params: WaterParams, z3: np.ndarray, vertical: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """E_c: sunlight dimmed over the vertical depth, plus the spot light at the camera (per channel)."""
    k_d = np.asarray(JERLOV_KD[params.water_type], dtype=np.float64)
    illumination = np.exp(-k_d * vertical)
    if params.artificial_light > 0:
        spot = np.exp(-((radius / params.light_cone) ** 2))[..., None]
        falloff = np.minimum(1.0, (_SPOT_REFERENCE_RANGE / z3) ** 2)
        illumination = illumination + params.artificial_light * spot * falloff * np.exp(-params.attenuation() * z3)
    return illumination


def direct_signal(water: WaterParams, z) -> np.ndarray:
    """The direct signal of a white scene point on the optical axis at range ``z`` (m), per channel:
    ``E_c(z) * exp(-beta^D_c z)``, its illumination (sunlight at the camera's depth, plus the spot light) times
    its transmission back to the camera, before forward scatter and exposure.

    Shapes
    ------
    z: (N,); returns: (N, 3) float64.
    """
    z3 = np.maximum(np.asarray(z, dtype=np.float64), 1e-9)[:, None]
    vertical = np.full(z3.shape, max(water.depth, 0.0))
    return _illumination(water, z3, vertical, np.zeros(z3.shape[0])) * np.exp(-water.attenuation() * z3)


def _radiance(clean_linear: np.ndarray, depth: np.ndarray, fx: float, params: WaterParams) -> np.ndarray:
    """Noise-free underwater radiance of one view (linear, before exposure)."""
    k_d = np.asarray(JERLOV_KD[params.water_type], dtype=np.float64)
    beta_d = params.attenuation()
    beta_b = np.asarray(params.backscatter_coef, dtype=np.float64)
    z, below_camera, radius = _view_geometry(depth, fx)
    z3 = z[..., None]
    vertical = np.maximum(params.depth + below_camera, 0.0)[..., None]
    illumination = _illumination(params, z3, vertical, radius)
    direct = (clean_linear * illumination * np.exp(-beta_d * z3)).astype(np.float32)
    width = depth.shape[1]
    sigma = params.forward_scatter * z * width / REFERENCE_WIDTH
    direct = _range_blur(direct, sigma)
    veil = np.asarray(params.veiling_light) * np.exp(-k_d * params.depth) * params.backscatter_strength
    backscatter = veil * (1.0 - np.exp(-beta_b * z3))
    return (direct + backscatter).astype(np.float32)


def _auto_exposure(radiance: np.ndarray) -> float:
    """Gain that brings the mean luminance to a mid-grey without clipping the highlights."""
    luminance = radiance @ _LUMINANCE
    mean = max(float(luminance.mean()), 1e-6)
    highlight = max(float(np.percentile(luminance, 99.0)), 1e-6)
    return min(_EXPOSURE_MEAN / mean, _EXPOSURE_HIGHLIGHT / highlight)


def _snow_layers(rng: np.random.Generator, shape: tuple, fx: float, params: WaterParams):
    """Marine-snow particles: (x_left, y, disparity, range, brightness, sigma) arrays."""
    height, width = shape
    count = rng.poisson(params.marine_snow * height * width / 1e6)
    x = rng.uniform(0, width, count)
    y = rng.uniform(0, height, count)
    z = rng.uniform(*_SNOW_RANGE, count)
    brightness = params.snow_brightness * rng.uniform(0.3, 1.0, count)
    sigma = rng.uniform(0.4, 1.2, count) * max(1.0, width / 640)
    return x, y, fx * params.baseline / z, z, brightness, sigma


def _render_snow(image: np.ndarray, particles, x_offset: np.ndarray, scene_range: np.ndarray) -> np.ndarray:
    """Add the particles that lie in front of the scene as Gaussian blobs (two size classes)."""
    x, y, _, z, brightness, sigma = particles
    height, width = scene_range.shape
    x = x - x_offset
    col = np.rint(x).astype(np.int64)
    row = np.rint(y).astype(np.int64)
    inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    visible = np.zeros(x.shape, dtype=bool)
    visible[inside] = z[inside] < scene_range[row[inside], col[inside]]
    out = image.copy()
    small = sigma < np.median(sigma) if sigma.size else np.zeros(0, dtype=bool)
    for group in (visible & small, visible & ~small):
        if not group.any():
            continue
        group_sigma = float(sigma[group].mean())
        impulses = np.zeros((height, width), dtype=np.float32)
        # A blob of peak b needs impulse weight b * 2 pi sigma^2 before the Gaussian blur.
        np.add.at(impulses, (row[group], col[group]), brightness[group] * 2 * np.pi * group_sigma**2)
        out += gaussian_blur(impulses, group_sigma)[..., None]
    return out


def _sensor(rng: np.random.Generator, linear: np.ndarray, params: WaterParams) -> np.ndarray:
    electrons = rng.poisson(np.clip(linear, 0.0, None) * params.full_well)
    noisy = electrons / params.full_well + rng.normal(0.0, params.read_noise, linear.shape)
    return linear_to_srgb(noisy)


def degrade(left, right, disparity, preset="coastal", seed: int = 0, **params):
    """Make an in-air stereo pair look underwater (same water for both views, own sensor noise each).

    Parameters
    ----------
    left, right : array_like of uint8
        sRGB images of a rectified pair.
    disparity : array_like
        Left-view disparity in px (non-finite or <= 0: unknown, treated as far).
    preset : str or WaterParams
        ``"clear"`` (Jerlov I), ``"coastal"`` (3C), ``"turbid"`` (9C, strong backscatter and blur)
        or ``"low_light"`` (dim, strong noise, artificial light); or a :class:`WaterParams`.
    seed : int
        Seed of marine snow and sensor noise; the output is a deterministic function of it.
    **params
        Overrides of :class:`WaterParams` fields (unknown names raise ``TypeError``).

    Returns
    -------
    left, right : numpy.ndarray
        Degraded uint8 sRGB images. The disparity is unchanged by construction.

    Shapes
    ------
    left, right: (H, W, 3); disparity: (H, W); returns: (H, W, 3) each.
    """
    water = resolve_params(preset, params)
    left = np.asarray(left)
    right = np.asarray(right)
    disp = np.asarray(disparity, dtype=np.float64)
    if left.shape != right.shape or left.ndim != 3 or left.shape[2] != 3 or disp.shape != left.shape[:2]:
        raise ValueError(
            f"degrade: expected (H, W, 3) images and an (H, W) disparity, got {left.shape}, {right.shape}, {disp.shape}"
        )
    width = left.shape[1]
    fx = water.focal_length(width)
    snow_rng, left_rng, right_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    depth_left = _depth_from_disparity(disp, fx, water)
    depth_right = _warp_depth_to_right(depth_left, disp)
    radiance_left = _radiance(srgb_to_linear(left), depth_left, fx, water)
    radiance_right = _radiance(srgb_to_linear(right), depth_right, fx, water)
    exposure = _auto_exposure(radiance_left)
    particles = _snow_layers(snow_rng, disp.shape, fx, water)
    outputs = []
    for rng, radiance, depth, shift in (
        (left_rng, radiance_left, depth_left, np.zeros_like(particles[2])),
        (right_rng, radiance_right, depth_right, particles[2]),
    ):
        exposed = _render_snow(radiance * exposure, particles, shift, _view_geometry(depth, fx)[0])
        outputs.append(_sensor(rng, exposed * water.gain, water))
    return outputs[0], outputs[1]


def texture_snr(left, disparity, preset="coastal", window: int = 9, texture_sigma: float = 3.0, **params) -> np.ndarray:
    """How visible the scene's texture stays in the degraded left view: per pixel, the signal-to-noise
    ratio of the texture carried by the direct signal, summed over a square window.

    The texture is what a blur of ``texture_sigma`` px removes from the clean image (fine detail and
    edges, the part stereo matching uses). With s_c the texture's share of the exposed, gained radiance
    of channel c (the same water, exposure and gain as :func:`degrade`, no marine snow) and sigma_c the
    standard deviation of that pixel's sensor noise, the ratio is the matched-filter SNR over the window:

        SNR = sqrt( sum over the window and the channels of s_c^2 / sigma_c^2 )

    Below about 1 the texture is lost in the noise, and where it covers a whole surface the surface's
    disparity cannot be found by matching at all, only guessed from its surroundings.

    Parameters
    ----------
    left : array_like of uint8
        Clean (in-air) sRGB left image.
    disparity : array_like
        Its disparity in px (as :func:`degrade`).
    preset, **params
        The water, as :func:`degrade`.
    window : int
        Side of the square window (odd, px).
    texture_sigma : float
        Sigma of the blur that separates texture from shading (px).

    Shapes
    ------
    left: (H, W, 3); disparity: (H, W); returns: (H, W) float32.
    """
    water = resolve_params(preset, params)
    left = np.asarray(left)
    disp = np.asarray(disparity, dtype=np.float64)
    if left.ndim != 3 or left.shape[2] != 3 or disp.shape != left.shape[:2]:
        raise ShapeError(f"texture_snr: expected an (H, W, 3) image and an (H, W) disparity, got {left.shape}, {disp.shape}")
    if window < 1 or window % 2 == 0:
        raise ArgumentError(f"texture_snr: window must be a positive odd number, got {window}")
    width = left.shape[1]
    fx = water.focal_length(width)
    depth = _depth_from_disparity(disp, fx, water)
    clean = srgb_to_linear(left)
    radiance = _radiance(clean, depth, fx, water)
    shading = _radiance(gaussian_blur(clean, texture_sigma), depth, fx, water)
    scale = _auto_exposure(radiance) * water.gain
    signal = (radiance - shading) * scale
    # Poisson-Gaussian noise of _sensor: variance = mean / full_well + read_noise^2 (linear units).
    noise_var = np.clip(radiance * scale, 0.0, None) / water.full_well + water.read_noise**2
    ratio = (signal**2 / noise_var).sum(axis=2)
    summed = box_sum(ratio, window)
    return np.sqrt(np.clip(summed, 0.0, None)).astype(np.float32)

