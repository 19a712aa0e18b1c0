"""Disparity -> depth -> point cloud, from a calibration dict as :func:`mipnet.stereo.io.read_calib` returns.

A calibration dict needs ``fx`` and ``baseline``; ``doffs`` (default 0), ``baseline_unit``
(``"m"``, ``"cm"`` or ``"mm"``; default ``"m"``), and for point clouds ``fy`` (default ``fx``),
``cx`` and ``cy`` (default: the image centre) are optional.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = ["disparity_to_depth", "depth_to_points", "baseline_in_metres"]

_UNIT_TO_METRES = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def baseline_in_metres(calib: Mapping) -> float:
    """The calibration's baseline converted to metres (``baseline_unit`` m, cm or mm; default m)."""
    unit = calib.get("baseline_unit", "m")
    if unit not in _UNIT_TO_METRES:
        raise ValueError(f"unknown baseline_unit {unit!r}; expected one of {sorted(_UNIT_TO_METRES)}")
    return float(calib["baseline"]) * _UNIT_TO_METRES[unit]


def disparity_to_depth(disp, calib: Mapping) -> np.ndarray:
    """Depth along the optical axis, ``Z = fx * B / (d + doffs)``, in metres.

    Pixels without a usable disparity (non-finite, ``d <= 0`` or ``d + doffs <= 0``) get depth
    ``+inf`` ("infinitely far / unknown"); :func:`depth_to_points` drops them.

    Parameters
    ----------
    disp : array_like
        Left-view disparity in pixels.
    calib : Mapping
        ``fx`` (px), ``baseline`` (in ``baseline_unit``), optional ``doffs`` (px).

    Returns
    -------
    numpy.ndarray
        float32 depth in metres.

    Shapes
    ------
    disp: (H, W) or any shape; return: same shape.
    """
    d = np.asarray(disp, dtype=np.float64)
    shifted = d + float(calib.get("doffs", 0.0))
    usable = np.isfinite(d) & (d > 0) & (shifted > 0)
    numerator = float(calib["fx"]) * baseline_in_metres(calib)
    depth = np.full(d.shape, np.inf)
    np.divide(numerator, shifted, out=depth, where=usable)
    return depth.astype(np.float32)


def depth_to_points(depth, calib: Mapping, image=None, valid=None, z_far: float | None = None):
    """Back-project a depth map to 3-D points in the left camera frame (x right, y down, z forward).

    ``X = (u - cx) * Z / fx``, ``Y = (v - cy) * Z / fy``. Pixels with non-finite or non-positive
    depth, outside ``valid``, or farther than ``z_far`` are dropped.

    Parameters
    ----------
    depth : array_like
        Depth in metres (as :func:`disparity_to_depth` returns).
    calib : Mapping
        ``fx``; optional ``fy`` (default ``fx``), ``cx``, ``cy`` (default: image centre).
    image : array_like of uint8, optional
        Left image for the point colours; gray (H, W) is replicated to RGB.
    valid : array_like of bool, optional
        Pixels to keep.
    z_far : float, optional
        Drop points with depth beyond this (metres).

    Returns
    -------
    points : numpy.ndarray
        float32 coordinates in metres, in row-major pixel order.
    colors : numpy.ndarray or None
        uint8 RGB per point, None without ``image``.

    Shapes
    ------
    depth, valid: (H, W); image: (H, W, 3) or (H, W); points: (N, 3); colors: (N, 3).
    """
    z = np.asarray(depth, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"depth_to_points: expected an (H, W) depth map, got shape {z.shape}")
    height, width = z.shape
    keep = np.isfinite(z) & (z > 0)
    if valid is not None:
        keep &= np.asarray(valid, dtype=bool)
    if z_far is not None:
        keep &= z <= z_far
    fx = float(calib["fx"])
    fy = float(calib.get("fy", fx))
    cx = float(calib.get("cx", (width - 1) / 2))
    cy = float(calib.get("cy", (height - 1) / 2))
    v, u = np.nonzero(keep)
    zk = z[v, u]
    points = np.stack([(u - cx) * zk / fx, (v - cy) * zk / fy, zk], axis=1).astype(np.float32)
    colors = None
    if image is not None:
        rgb = np.asarray(image)
        if rgb.ndim == 2:
            rgb = rgb[:, :, None]
        if rgb.shape[:2] != (height, width):
            raise ValueError(f"depth_to_points: image shape {rgb.shape} does not match depth {z.shape}")
        colors = np.ascontiguousarray(np.broadcast_to(rgb[v, u], (len(v), 3)), dtype=np.uint8)
    return points, colors
