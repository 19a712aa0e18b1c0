"""Colour maps for disparity, depth and error maps, without matplotlib."""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["colorize", "colormap_lut", "COLORMAPS"]

# Polynomial approximation of Google's Turbo colour map (Anton Mikhailov, 2019, Apache-2.0 gist):
# channel(x) = sum_k c_k x^k for k = 0..5, x in [0, 1]. It stays within ~6/255 (mean) of the
# reference Turbo table, with its largest deviations (up to ~30/255) at the two dark ends.
_TURBO_POLY = np.array(
    [
        [0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943],
        [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604],
        [0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973],
    ]
)


def _turbo(x: np.ndarray) -> np.ndarray:
    powers = x[:, None] ** np.arange(6)[None, :]
    return powers @ _TURBO_POLY.T


def _jet(x: np.ndarray) -> np.ndarray:
    # Classic jet: each channel is a trapezoid centred at 0.75 (R), 0.5 (G), 0.25 (B).
    centres = np.array([0.75, 0.5, 0.25])
    return 1.5 - np.abs(4.0 * (x[:, None] - centres[None, :]))


def _gray(x: np.ndarray) -> np.ndarray:
    return np.repeat(x[:, None], 3, axis=1)


_BUILDERS = {"turbo": _turbo, "jet": _jet, "gray": _gray}
COLORMAPS = tuple(_BUILDERS)


@functools.cache
def colormap_lut(name: str = "turbo") -> np.ndarray:
    """The 256-entry lookup table of a colour map.

    Parameters
    ----------
    name : str
        One of :data:`COLORMAPS` (``"turbo"``, ``"jet"``, ``"gray"``).

    Returns
    -------
    numpy.ndarray
        uint8 RGB table (read-only).

    Shapes
    ------
    return: (256, 3).
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown colour map {name!r}; available: {', '.join(COLORMAPS)}")
    x = np.linspace(0.0, 1.0, 256)
    lut = np.rint(np.clip(_BUILDERS[name](x), 0.0, 1.0) * 255).astype(np.uint8)
    lut.setflags(write=False)
    return lut


def colorize(disp, vmin=None, vmax=None, cmap: str = "turbo", valid=None) -> np.ndarray:
    """Map a scalar image (disparity, depth, error) to RGB uint8.

    Parameters
    ----------
    disp : array_like
        Values to colour.
    vmin, vmax : float, optional
        Value range mapped to the ends of the colour map; defaults are the 1st and 99th
        percentiles of the valid finite values. Fix them to keep colours stable across a video.
    cmap : str
        ``"turbo"`` (default), ``"jet"`` or ``"gray"``.
    valid : array_like of bool, optional
        Pixels to colour; the others, and non-finite values, are painted black.

    Returns
    -------
    numpy.ndarray
        uint8 RGB image.

    Shapes
    ------
    disp, valid: (H, W); return: (H, W, 3).
    """
    values = np.asarray(disp, dtype=np.float64)
    if values.ndim != 2:
        raise ValueError(f"colorize: expected an (H, W) map, got shape {values.shape}")
    lut = colormap_lut(cmap)
    mask = np.isfinite(values)
    if valid is not None:
        mask &= np.asarray(valid, dtype=bool)
    out = np.zeros(values.shape + (3,), dtype=np.uint8)
    if not mask.any():
        return out
    if vmin is None or vmax is None:
        low, high = np.percentile(values[mask], [1, 99])
        vmin = low if vmin is None else vmin
        vmax = high if vmax is None else vmax
    span = max(float(vmax) - float(vmin), 1e-12)
    scaled = np.clip((values[mask] - float(vmin)) / span, 0.0, 1.0)
    out[mask] = lut[np.rint(scaled * 255).astype(np.intp)]
    return out
