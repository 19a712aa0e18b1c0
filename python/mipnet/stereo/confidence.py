"""Where a disparity map is backed by the images: the match confidence of each pixel.

A network answers everywhere, also where the images hold no answer: open water, sky, a wall without texture, a
surface only one camera sees. There its output is a guess from the surroundings (for the shipped weights, open
water under a turbid veil reads as a surface 3-4 m away). :func:`match_confidence` tells the two apart after the
fact, from the images and the disparity alone: it correlates the left view's fine detail with the right view's
at the matched position, both band-passed. Where the surface's texture is seen by both cameras and the disparity is right, the
two agree (confidence near 1); where the pixel shows only sensor noise (a featureless veil), where the disparity
is wrong, or where the match falls outside the right image, the correlation is that of independent noise: near
0, within about ``2.5 / window`` of it.

This is the classic correlation confidence of stereo (the normalised cross-correlation at the chosen disparity;
Hu and Mordohai, "A quantitative evaluation of confidence measures for stereo vision", TPAMI 2012), applied to
high-passed images so that shading, veiling light and exposure differences between the cameras do not count
as agreement. ``mipnet infer --min-confidence C`` marks pixels below ``C`` invalid (``inf``), as SGBM's texture
threshold and uniqueness check do.
"""

from __future__ import annotations

import numpy as np

from ..errors import ArgumentError, ShapeError
from .filters import box_sum, gaussian_blur

__all__ = ["match_confidence"]


def match_confidence(left, right, disparity, window: int = 15, noise_sigma: float = 1.0,
                     shading_sigma: float = 8.0) -> np.ndarray:
    """Per-pixel normalised cross-correlation of the two views' fine detail at the left view's disparity.

    With a = the left image's detail (its grey level band-passed: a Gaussian blur of ``noise_sigma`` px, which
    averages away most pixel noise, minus one of ``shading_sigma`` px, which holds the shading) and b = the
    right image's detail sampled at (x - d(x), y) (linear interpolation), both summed over the square window
    W around the pixel:

        confidence = sum_W a b / sqrt(sum_W a^2 * sum_W b^2)

    Pixels whose match falls outside the right image (or whose disparity is not finite) contribute nothing,
    and their own confidence is 0; so is that of a window without any detail (a flat or saturated patch).

    Parameters
    ----------
    left, right : array_like
        The rectified pair, (H, W, C) colour or (H, W) grey, any numeric dtype (uint8 sRGB as read).
    disparity : array_like
        Left-view disparity in px (as :class:`mipnet.MIPNet` returns).
    window : int
        Side of the square window (odd, px). The wider, the smaller the spread of the confidence of pure noise
        (about 2.5 / window with the default band) and the blurrier the map.
    noise_sigma, shading_sigma : float
        The band of the detail (Gaussian sigmas, px, 0 <= noise_sigma < shading_sigma): finer structure counts
        as noise, broader as shading.

    Returns
    -------
    numpy.ndarray
        float32 in [-1, 1]: about 0 where nothing was matched, towards 1 where both views show the same texture.

    Shapes
    ------
    left, right: (H, W, C) or (H, W); disparity: (H, W); returns: (H, W).
    """
    left, right = np.asarray(left), np.asarray(right)
    disparity = np.asarray(disparity, dtype=np.float32)
    if left.shape != right.shape or left.ndim not in (2, 3) or disparity.shape != left.shape[:2]:
        raise ShapeError(f"match_confidence: expected two (H, W, C) or (H, W) images of one shape and an (H, W) "
                         f"disparity, got left {left.shape}, right {right.shape}, disparity {disparity.shape}")
    for name, image in (("left", left), ("right", right)):
        if not (np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)):
            raise ArgumentError(f"match_confidence: {name} image has unsupported dtype {image.dtype}")
        if not np.isfinite(image).all():
            raise ArgumentError(f"match_confidence: {name} image {image.shape} contains NaN or inf")
    if not (isinstance(window, (int, np.integer)) and window >= 1 and window % 2 == 1):
        raise ArgumentError(f"match_confidence: window must be a positive odd integer, got {window!r}")
    if not 0 <= noise_sigma < shading_sigma:
        raise ArgumentError(f"match_confidence: need 0 <= noise_sigma < shading_sigma, got {noise_sigma!r}, {shading_sigma!r}")
    left_detail, right_detail = (_detail(image, noise_sigma, shading_sigma) for image in (left, right))
    matched, seen = _sample_rows(right_detail, disparity)
    a = np.where(seen, left_detail, 0.0).astype(np.float32)
    b = np.where(seen, matched, 0.0).astype(np.float32)
    energy = box_sum(a * a, window) * box_sum(b * b, window)
    correlation = box_sum(a * b, window)
    confidence = np.divide(correlation, np.sqrt(energy), out=np.zeros_like(correlation), where=energy > 0)
    confidence[~seen] = 0.0
    return np.clip(confidence, -1.0, 1.0).astype(np.float32)


def _detail(image: np.ndarray, noise_sigma: float, shading_sigma: float) -> np.ndarray:
    """The grey level (mean of the channels), band-passed: the texture, without the pixel noise and the shading."""
    grey = image.astype(np.float32)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    return gaussian_blur(grey, noise_sigma) - gaussian_blur(grey, shading_sigma)


def _sample_rows(image: np.ndarray, disparity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``image`` at (x - d, y) by linear interpolation along the row, and where that lies inside the image."""
    height, width = image.shape
    # column of the match: x_r = x - d(x, y)
    source = np.arange(width, dtype=np.float32)[None, :] - disparity
    seen = np.isfinite(source) & (source >= 0) & (source <= width - 1)
    source = np.where(seen, source, 0.0)
    lower = np.minimum(np.floor(source).astype(np.intp), width - 2) if width > 1 else np.zeros_like(source, dtype=np.intp)
    upper = np.minimum(lower + 1, width - 1)
    fraction = source - lower
    rows = np.arange(height)[:, None]
    # image(x_r) = (1 - f) image[floor x_r] + f image[floor x_r + 1]
    return (1.0 - fraction) * image[rows, lower] + fraction * image[rows, upper], seen
