"""Colour maps for disparity, depth and error maps, without matplotlib.

Turbo is Google's exact 256-entry table (Anton Mikhailov, "Turbo, An Improved Rainbow Colormap for
Visualization", Google AI blog, 2019; Apache License 2.0), shipped as ``assets/turbo_colormap.npy``
(uint8, 256x3). It was generated once from matplotlib's copy of the table,
``np.rint(np.asarray(matplotlib._cm_listed._turbo_data) * 255).astype(np.uint8)``, so it does not depend on
matplotlib or OpenCV being installed. Jet and gray are computed.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

__all__ = ["colorize", "colormap_lut", "COLORMAPS"]

_TURBO_PATH = Path(__file__).resolve().parents[1] / "assets" / "turbo_colormap.npy"


def _turbo(x: np.ndarray) -> np.ndarray:
    # the table's entry i is the colour at i / 255: x = linspace(0, 1, 256) reads every entry once
    table = np.load(_TURBO_PATH, allow_pickle=False).astype(np.float64) / 255.0
    return table[np.rint(x * 255).astype(np.intp)]


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
