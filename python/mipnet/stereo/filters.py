"""Separable image filters in numpy (Gaussian blur, box sums), shared by the water model, the scene generator
and the match confidence. Borders reflect; every function keeps the input's shape and returns float32."""

from __future__ import annotations

import numpy as np

__all__ = ["gaussian_kernel", "convolve_axis", "gaussian_blur", "box_sum"]


def gaussian_kernel(sigma: float) -> np.ndarray:
    """Normalised 1-D Gaussian of ``sigma`` px, radius ceil(3 sigma) (at least 1)."""
    radius = max(1, int(np.ceil(3.0 * sigma)))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    return (kernel / kernel.sum()).astype(np.float32)


def convolve_axis(image: np.ndarray, kernel: np.ndarray, axis: int) -> np.ndarray:
    """``image`` convolved with the odd-length 1-D ``kernel`` along ``axis`` (reflected borders)."""
    radius = len(kernel) // 2
    pad = [(0, 0)] * image.ndim
    pad[axis] = (radius, radius)
    padded = np.pad(image, pad, mode="reflect" if image.shape[axis] > radius else "edge")
    out = np.zeros_like(image)
    length = image.shape[axis]
    for k, weight in enumerate(kernel):
        # out[i] += kernel[k] * image[i + k - radius], i.e. padded[i + k]
        window = [slice(None)] * image.ndim
        window[axis] = slice(k, k + length)
        out += weight * padded[tuple(window)]
    return out


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur over the first two axes (``sigma <= 0``: a copy).

    Shapes
    ------
    image: (H, W) or (H, W, C); return: same shape, float32.
    """
    image = np.asarray(image, dtype=np.float32)
    if sigma <= 0:
        return image.copy()
    kernel = gaussian_kernel(sigma)
    return convolve_axis(convolve_axis(image, kernel, 0), kernel, 1)


def box_sum(image: np.ndarray, window: int) -> np.ndarray:
    """Sum over the ``window`` x ``window`` square around each pixel of the first two axes (``window`` odd).

    Shapes
    ------
    image: (H, W) or (H, W, C); return: same shape, float32.
    """
    ones = np.ones(window, dtype=np.float32)
    return convolve_axis(convolve_axis(np.asarray(image, dtype=np.float32), ones, 0), ones, 1)
