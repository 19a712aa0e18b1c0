"""Self-supervised stereo losses: the photometric reconstruction of the left view, its masks, and
edge-aware smoothness (architecture.md §3.1 for the supervised counterpart; used by ``mipnet adapt``).

The left view is reconstructed from the right one warped by a left-view disparity ``d``: left pixel
``(x, y)`` reads the right image at ``(x - d, y)`` (architecture.md §1). The reconstruction error is
Monodepth2's ``alpha (1 - SSIM) / 2 + (1 - alpha) |I_L - I_R(x - d)|`` with ``alpha = 0.85`` and SSIM over
3x3 windows (average pooling of replicate-padded images), on images scaled to ``[0, 1]``.

The engine has no ``abs``, ``exp`` or tensor division; they are composed here from its ops:

- ``|x|`` is ``sign(x) * x`` with the sign held constant: gradient ``sign(x)`` (0 at 0, as torch's);
- ``a / b`` is linearised around its value: ``q0 = a / b`` computed on the arrays, then
  ``q = q0 + (a - q0 b) / b`` with ``1 / b`` held constant, which has the value ``q0`` (up to rounding) and
  exactly the gradients ``1 / b`` and ``-q0 / b`` of a division;
- ``exp`` appears only in the smoothness weight ``exp(-|dI|)`` of the image, which needs no gradient.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import ops
from ..errors import ShapeError
from ..tensor import Tensor

__all__ = ["SSIM_ALPHA", "warp_right_to_left", "in_image_mask", "lr_consistency_mask", "ssim_distance",
           "photometric_error", "photometric_loss", "smoothness_loss"]

#: Weight of the SSIM term in the reconstruction error (Monodepth2).
SSIM_ALPHA = 0.85
#: SSIM's stabilising constants for values in [0, 1]: (0.01)^2 and (0.03)^2.
_C1, _C2 = 0.01 ** 2, 0.03 ** 2


def _const(a: Any, like: Tensor) -> Tensor:
    """``a`` as a constant Tensor of ``like``'s dtype."""
    return Tensor(np.ascontiguousarray(np.asarray(a.numpy() if isinstance(a, Tensor) else a, dtype=like.dtype)))


def _abs(x: Tensor) -> Tensor:
    """|x| = sign(x) * x, the sign held constant (gradient sign(x))."""
    return x * _const(np.sign(x.numpy()), x)


def _divide(a: Tensor, b: Tensor) -> Tensor:
    """a / b, broadcasting: q0 + (a - q0 b) / b with q0 = a / b and 1 / b held constant."""
    q0 = a.numpy() / b.numpy()
    return (a - b * _const(q0, b)) * _const(1.0 / b.numpy(), b) + _const(q0, b)


def _check_pair(function: str, image: Tensor, disp: Tensor) -> tuple[int, int, int]:
    if image.ndim != 4 or disp.ndim != 4 or disp.shape[1] != 1 or image.shape[0] != disp.shape[0] \
            or image.shape[2:] != disp.shape[2:]:
        raise ShapeError(f"{function}: needs an image (N,C,H,W) and a disparity (N,1,H,W) of one N, H, W; "
                         f"got image={list(image.shape)} disparity={list(disp.shape)}")
    n, _, h, w = image.shape
    return n, h, w


def _as_tensor(a: Any, dtype: Any) -> Tensor:
    return a if isinstance(a, Tensor) else Tensor(np.ascontiguousarray(np.asarray(a, dtype=dtype)))


def warp_right_to_left(right: Any, disp: Tensor) -> Tensor:
    """The right image read at ``(x - d(x, y), y)``: the left view's reconstruction.

    Bilinear (``ops.grid_sample``, zeros outside, ``align_corners=True``), differentiable with respect to
    the disparity and the image.

    Shapes
    ------
    right (N, C, H, W), disp (N, 1, H, W) -> (N, C, H, W).
    """
    disp = _as_tensor(disp, np.float32)
    right = _as_tensor(right, disp.dtype)
    n, h, w = _check_pair("warp_right_to_left", right, disp)
    ys, xs = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64), indexing="ij")
    # align_corners=True: g = 2 p / (size - 1) - 1, so g_x = 2 (x - d) / (W - 1) - 1 and g_y = 2 y / (H - 1) - 1
    sx, sy = 2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)
    gx = ops.permute(disp, (0, 2, 3, 1)) * (-sx) + _const(np.broadcast_to((xs * sx - 1)[None, :, :, None], (n, h, w, 1)), disp)
    gy = _const(np.broadcast_to((ys * sy - 1)[None, :, :, None], (n, h, w, 1)), disp)
    return ops.grid_sample(right, ops.cat([gx, gy], dim=3), padding_mode="zeros", align_corners=True)


def in_image_mask(disp: Any) -> np.ndarray:
    """Where the matching right pixel ``x - d`` lies inside the image, ``0 <= x - d <= W - 1`` (no gradient).

    Shapes
    ------
    disp (N, 1, H, W) -> bool (N, 1, H, W).
    """
    d = np.asarray(disp.numpy() if isinstance(disp, Tensor) else disp)
    x = np.arange(d.shape[-1])
    # the source column of left pixel x is x - d(x)
    source = x - d
    return (source >= 0) & (source <= d.shape[-1] - 1)


def lr_consistency_mask(disp_left: Any, disp_right: Any, threshold: float = 1.0) -> np.ndarray:
    """Left pixels whose disparity the right view confirms: ``|d_L(x) - d_R(x - d_L(x))| <= threshold``.

    ``d_R`` is the right view's disparity, indexed by right-image pixels (a right pixel ``x_r`` matches left
    ``x_r + d_R``), read with linear interpolation along the row, clamped at the border. False marks a left
    pixel that is occluded in the right view or whose match is inconsistent. No gradient.

    Shapes
    ------
    disp_left, disp_right: (N, 1, H, W) or (N, H, W) -> bool of that shape.
    """
    dl = np.asarray(disp_left.numpy() if isinstance(disp_left, Tensor) else disp_left, dtype=np.float64)
    dr = np.asarray(disp_right.numpy() if isinstance(disp_right, Tensor) else disp_right, dtype=np.float64)
    if dl.shape != dr.shape or dl.ndim not in (3, 4):
        raise ShapeError(f"lr_consistency_mask: both disparities must be (N,1,H,W) or (N,H,W) of one shape, "
                         f"got disp_left={list(dl.shape)} disp_right={list(dr.shape)}")
    w = dl.shape[-1]
    # X = clamp(x - d_L(x), 0, W - 1); x0 = floor(X), x1 = min(x0 + 1, W - 1), a = X - x0
    source = np.clip(np.arange(w) - dl, 0, w - 1)
    x0 = np.floor(source).astype(np.int64)
    x1 = np.minimum(x0 + 1, w - 1)
    a = source - x0
    sampled = (1 - a) * np.take_along_axis(dr, x0, axis=-1) + a * np.take_along_axis(dr, x1, axis=-1)
    return np.abs(dl - sampled) <= threshold


def _local_mean(x: Tensor) -> Tensor:
    """3x3 box mean over replicate-padded borders (same size)."""
    return ops.avg_pool2d(ops.pad(x, [1, 1, 1, 1], mode="replicate"), 3, stride=1)


def ssim_distance(x: Any, y: Tensor) -> Tensor:
    """(1 - SSIM(x, y)) / 2 per pixel and channel over 3x3 windows, clamped to [0, 1] (Monodepth2).

    ``SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x + s_y + C2))`` with box means and
    (co)variances over each 3x3 window; values in [0, 1], C1 = 0.01^2, C2 = 0.03^2.

    Shapes
    ------
    x, y: (N, C, H, W) -> (N, C, H, W).
    """
    x = _as_tensor(x, y.dtype)
    mu_x, mu_y = _local_mean(x), _local_mean(y)
    var_x = _local_mean(x * x) - mu_x * mu_x
    var_y = _local_mean(y * y) - mu_y * mu_y
    cov = _local_mean(x * y) - mu_x * mu_y
    numerator = (mu_x * mu_y * 2.0 + _C1) * (cov * 2.0 + _C2)
    denominator = (mu_x * mu_x + mu_y * mu_y + _C1) * (var_x + var_y + _C2)
    distance = (1.0 - _divide(numerator, denominator)) * 0.5
    # clamp(v, 0, 1) = relu(v) - relu(v - 1)
    return ops.relu(distance) - ops.relu(distance - 1.0)


def photometric_error(left: Any, right: Any, disp: Tensor, alpha: float = SSIM_ALPHA) -> Tensor:
    """Per-pixel reconstruction error of the left view, ``alpha (1 - SSIM) / 2 + (1 - alpha) |I_L - W(I_R)|``,
    averaged over the colour channels; images 0..255 (scaled to [0, 1] here).

    Shapes
    ------
    left, right (N, C, H, W) arrays or Tensors, disp (N, 1, H, W) -> (N, 1, H, W).
    """
    disp = _as_tensor(disp, np.float32)
    left = _as_tensor(np.asarray(left.numpy() if isinstance(left, Tensor) else left) / 255.0, disp.dtype)
    right = _as_tensor(np.asarray(right.numpy() if isinstance(right, Tensor) else right) / 255.0, disp.dtype)
    _check_pair("photometric_error", left, disp)
    if right.shape != left.shape:
        raise ShapeError(f"photometric_error: left and right differ in shape: left={list(left.shape)} "
                         f"right={list(right.shape)}")
    warped = warp_right_to_left(right, disp)
    l1 = _abs(warped - left)
    error = ssim_distance(left, warped) * float(alpha) + l1 * float(1.0 - alpha)
    return ops.mean(error, dim=1, keepdim=True)


def photometric_loss(left: Any, right: Any, disp: Tensor, mask: Any = None, alpha: float = SSIM_ALPHA) -> Tensor:
    """Mean of :func:`photometric_error` over the pixels where ``mask`` (e.g. an occlusion mask) holds and the
    match lies inside the right image (:func:`in_image_mask`); 0 when no pixel is left (a 0-d Tensor).

    Shapes
    ------
    left, right (N, C, H, W), disp (N, 1, H, W), mask bool (N, 1, H, W) or None -> a 0-d Tensor.
    """
    disp = _as_tensor(disp, np.float32)
    keep = in_image_mask(disp)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != keep.shape:
            raise ShapeError(f"photometric_loss: mask must be {list(keep.shape)} like the disparity, got {list(m.shape)}")
        keep &= m
    count = int(keep.sum())
    error = photometric_error(left, right, disp, alpha)
    # mean over kept pixels = sum(error * keep) / count
    return ops.sum(error * _const(keep, disp)) * (1.0 / max(count, 1))


def smoothness_loss(disp: Tensor, image: Any) -> Tensor:
    """Edge-aware smoothness of the disparity normalised by its mean (Monodepth2):
    ``mean |dd*/dx| exp(-|dI/dx|) + mean |dd*/dy| exp(-|dI/dy|)``, ``d* = d / mean_HW(d)`` per image, ``|dI|``
    the mean over colour channels of the image's differences on [0, 1]. The mean is taken as at least
    1e-3 px (an untrained network's disparities can be negative).

    Shapes
    ------
    disp (N, 1, H, W), image (N, C, H, W) 0..255 -> a 0-d Tensor.
    """
    disp = _as_tensor(disp, np.float32)
    img = np.asarray(image.numpy() if isinstance(image, Tensor) else image, dtype=np.float64) / 255.0
    _check_pair("smoothness_loss", _const(img, disp), disp)
    norm = _divide(disp, ops.relu(ops.mean(disp, dim=(2, 3), keepdim=True)) + 1e-3)
    h, w = disp.shape[2:]
    # forward differences: dx(x) = d(x + 1) - d(x) over columns 0..W-2, dy likewise over rows 0..H-2
    dx = _abs(ops.narrow(norm, 3, 1, w - 1) - ops.narrow(norm, 3, 0, w - 1))
    dy = _abs(ops.narrow(norm, 2, 1, h - 1) - ops.narrow(norm, 2, 0, h - 1))
    wx = np.exp(-np.abs(img[:, :, :, 1:] - img[:, :, :, :-1]).mean(axis=1, keepdims=True))
    wy = np.exp(-np.abs(img[:, :, 1:, :] - img[:, :, :-1, :]).mean(axis=1, keepdims=True))
    return ops.mean(dx * _const(wx, disp)) + ops.mean(dy * _const(wy, disp))
