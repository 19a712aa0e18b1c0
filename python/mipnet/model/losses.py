"""MIPNet's training loss (architecture.md §3.1)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .. import ops
from ..errors import ArgumentError, ShapeError
from ..tensor import Tensor

__all__ = ["valid_mask", "near_jump", "sequence_loss", "sequence_metrics"]

#: Distance (px, a square window) from a ground-truth depth jump within which ``sequence_loss``'s ``edge_weight``
#: term counts a pixel: the band where the network bleeds disparity across depth edges (docs/training.md).
EDGE_RADIUS = 12
#: A jump: more than this many pixels between the disparities of two neighbouring valid pixels.
EDGE_JUMP = 2.0


def _as_n1hw(a: Any, name: str, like: Tensor) -> np.ndarray:
    arr = np.asarray(a.numpy() if isinstance(a, Tensor) else a)
    if arr.ndim == 3:
        arr = arr[:, None]
    if arr.shape != like.shape:
        raise ShapeError(f"sequence_loss: {name} must be (N,1,H,W) or (N,H,W) matching the predictions "
                         f"{list(like.shape)}, got {list(np.shape(a))}")
    return arr


def valid_mask(gt: np.ndarray, valid: np.ndarray | None, max_disp: float) -> np.ndarray:
    """valid >= 0.5 (or True) AND finite gt AND |gt| < max_disp."""
    ok = np.isfinite(gt) & (np.abs(np.nan_to_num(gt, nan=np.inf)) < max_disp)
    if valid is not None:
        ok &= np.asarray(valid, dtype=np.float64) >= 0.5
    return ok


def _dilate(mask: np.ndarray, radius: int, axis: int) -> np.ndarray:
    """``mask`` grown by ``radius`` positions both ways along ``axis`` (a running window count)."""
    n = mask.shape[axis]
    # counts[i] = number of set positions before i; window [i - r, i + r] holds counts[i + r + 1] - counts[i - r], clipped
    first = np.zeros_like(np.take(mask, [0], axis=axis), dtype=np.int64)
    counts = np.concatenate([first, np.cumsum(mask, axis=axis, dtype=np.int64)], axis=axis)
    index = np.arange(n)
    return np.take(counts, np.minimum(index + radius + 1, n), axis=axis) > np.take(counts, np.maximum(index - radius, 0), axis=axis)


def near_jump(gt: np.ndarray, ok: np.ndarray, radius: int = EDGE_RADIUS, jump: float = EDGE_JUMP) -> np.ndarray:
    """The ``ok`` pixels within ``radius`` px (a square window) of a jump of more than ``jump`` px between the
    disparities ``gt`` of two horizontally or vertically neighbouring ``ok`` pixels; arrays (..., H, W)."""
    edge = np.zeros(ok.shape, bool)
    # neighbours (y, x) and (y, x + 1), then (y, x) and (y + 1, x)
    h = ok[..., :, 1:] & ok[..., :, :-1] & (np.abs(gt[..., :, 1:] - gt[..., :, :-1]) > jump)
    v = ok[..., 1:, :] & ok[..., :-1, :] & (np.abs(gt[..., 1:, :] - gt[..., :-1, :]) > jump)
    edge[..., :, 1:] |= h
    edge[..., :, :-1] |= h
    edge[..., 1:, :] |= v
    edge[..., :-1, :] |= v
    return _dilate(_dilate(edge, radius, -1), radius, -2) & ok


def sequence_loss(preds: Sequence[Tensor], gt: Any, valid: Any = None, gamma: float = 0.8,
                  max_disp: float = 700.0, edge_weight: float = 0.0) -> Tensor:
    """L = Σ_i gamma^(n-1-i) · (mean_{valid} |d_i - d_gt| + edge_weight · mean_{near a jump} |d_i - d_gt|) over
    the n predictions (a 0-d Tensor); "near a jump": the valid pixels of :func:`near_jump`.

    Invalid ground truth is zeroed before the subtraction, so NaN/inf there never reaches the
    gradient; a prediction with no valid pixel (no pixel near a jump) contributes 0 (to that term).

    Shapes:
        preds: n Tensors (N,1,H,W); gt, valid: (N,1,H,W) or (N,H,W) arrays or Tensors.
    """
    if not preds:
        raise ArgumentError("sequence_loss: needs at least one prediction")
    ref = preds[-1]
    gt_arr = _as_n1hw(gt, "gt", ref)
    ok = valid_mask(gt_arr, None if valid is None else _as_n1hw(valid, "valid", ref), max_disp)
    target = np.where(ok, gt_arr, 0).astype(ref.dtype)
    weight = ok.astype(ref.dtype)
    edge = near_jump(target, ok).astype(ref.dtype) if edge_weight else None
    n = len(preds)

    def term(p: Tensor) -> Tensor:
        l1 = ops.masked_l1_loss(p, target, weight)
        return l1 if edge is None else l1 + ops.masked_l1_loss(p, target, edge) * float(edge_weight)

    terms = [term(p) * float(gamma ** (n - 1 - i)) for i, p in enumerate(preds)]
    total = terms[0]
    for t in terms[1:]:
        total = total + t
    return total


def sequence_metrics(pred: Tensor | np.ndarray, gt: Any, valid: Any = None, max_disp: float = 700.0) -> dict:
    """EPE and the share of valid pixels with error < 1, 3, 5 px of one prediction (RAFT-Stereo's
    training metrics)."""
    p = np.asarray(pred.numpy() if isinstance(pred, Tensor) else pred, dtype=np.float64)
    g = np.asarray(gt.numpy() if isinstance(gt, Tensor) else gt, dtype=np.float64).reshape(p.shape)
    v = None if valid is None else np.asarray(valid.numpy() if isinstance(valid, Tensor) else valid).reshape(p.shape)
    ok = valid_mask(g, v, max_disp)
    e = np.abs(p - np.where(ok, g, 0))[ok]
    if e.size == 0:
        return {"epe": float("nan"), "1px": float("nan"), "3px": float("nan"), "5px": float("nan")}
    return {"epe": float(e.mean()), "1px": float((e < 1).mean()), "3px": float((e < 3).mean()),
            "5px": float((e < 5).mean())}
