"""Classical baselines to compare against (OpenCV semi-global matching)."""

from __future__ import annotations

import numpy as np

__all__ = ["sgbm", "default_num_disparities"]

_MODES = ("sgbm", "hh", "sgbm_3way", "hh4")


def _import_cv2():
    try:
        import cv2
    except ImportError as exc:
        raise ImportError(
            "mipnet.stereo.baselines.sgbm needs OpenCV: pip install opencv-python-headless"
        ) from exc
    return cv2


def default_num_disparities(width: int) -> int:
    """The smallest multiple of 16 that covers ``width / 4`` pixels (at least 16)."""
    return max(16, 16 * int(np.ceil(width / 4 / 16)))


def sgbm(
    left,
    right,
    num_disparities: int | None = None,
    block_size: int = 5,
    min_disparity: int = 0,
    p1: int | None = None,
    p2: int | None = None,
    uniqueness_ratio: int = 10,
    speckle_window_size: int = 100,
    speckle_range: int = 2,
    disp12_max_diff: int = 1,
    pre_filter_cap: int = 63,
    mode: str = "sgbm_3way",
):
    """Disparity by OpenCV's StereoSGBM.

    Parameters
    ----------
    left, right : array_like of uint8
        Rectified RGB (H, W, 3) or gray (H, W) images.
    num_disparities : int, optional
        Search range (multiple of 16); default: the smallest multiple of 16 covering W / 4.
    block_size : int
        Matched block size (odd).
    min_disparity : int
        Smallest disparity searched.
    p1, p2 : int, optional
        Smoothness penalties; defaults ``8 * C * block_size**2`` and ``32 * C * block_size**2``
        (C = channels), as the OpenCV samples use.
    uniqueness_ratio, speckle_window_size, speckle_range, disp12_max_diff, pre_filter_cap : int
        Passed to ``cv2.StereoSGBM_create``.
    mode : str
        ``"sgbm"``, ``"hh"``, ``"sgbm_3way"`` (default) or ``"hh4"``.

    Returns
    -------
    disparity : numpy.ndarray
        float32 disparity in px (OpenCV's fixed point / 16); 0 where invalid.
    valid : numpy.ndarray
        bool; False where SGBM found no match (it writes ``(min_disparity - 1) * 16`` there).

    Shapes
    ------
    left, right: (H, W, 3) or (H, W); disparity, valid: (H, W).
    """
    cv2 = _import_cv2()
    left = np.ascontiguousarray(left, dtype=np.uint8)
    right = np.ascontiguousarray(right, dtype=np.uint8)
    if left.shape != right.shape:
        raise ValueError(f"sgbm: left {left.shape} and right {right.shape} differ in shape")
    if mode not in _MODES:
        raise ValueError(f"sgbm: unknown mode {mode!r}; expected one of {_MODES}")
    channels = 1 if left.ndim == 2 else left.shape[2]
    if num_disparities is None:
        num_disparities = default_num_disparities(left.shape[1])
    matcher = cv2.StereoSGBM_create(
        minDisparity=min_disparity,
        numDisparities=num_disparities,
        blockSize=block_size,
        P1=8 * channels * block_size**2 if p1 is None else p1,
        P2=32 * channels * block_size**2 if p2 is None else p2,
        disp12MaxDiff=disp12_max_diff,
        preFilterCap=pre_filter_cap,
        uniquenessRatio=uniqueness_ratio,
        speckleWindowSize=speckle_window_size,
        speckleRange=speckle_range,
        mode=getattr(cv2, f"STEREO_SGBM_MODE_{mode.upper()}"),
    )
    raw = matcher.compute(left, right)
    # OpenCV's disparity is fixed point with 4 fractional bits; unmatched pixels are (min - 1) * 16.
    valid = raw >= min_disparity * 16
    disparity = np.where(valid, raw.astype(np.float32) / 16.0, np.float32(0.0)).astype(np.float32)
    return disparity, valid
