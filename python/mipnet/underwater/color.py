"""sRGB <-> linear RGB (IEC 61966-2-1), the colour space the image-formation model works in."""

from __future__ import annotations

import numpy as np

__all__ = ["srgb_to_linear", "linear_to_srgb"]


def srgb_to_linear(image) -> np.ndarray:
    """sRGB uint8 -> linear float32 in [0, 1] (IEC 61966-2-1).

    Shapes
    ------
    image: any; return: same shape.
    """
    s = np.asarray(image, dtype=np.float32) / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(linear) -> np.ndarray:
    """Linear float (clipped to [0, 1]) -> sRGB uint8.

    Shapes
    ------
    linear: any; return: same shape.
    """
    x = np.clip(np.asarray(linear, dtype=np.float32), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(s * 255.0).astype(np.uint8)
