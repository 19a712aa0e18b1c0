"""MIPNet's training loss (architecture.md §3.1)."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .. import ops
from ..errors import ArgumentError, ShapeError
from ..tensor import Tensor

__all__ = ["valid_mask", "sequence_loss", "sequence_metrics"]


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


def sequence_loss(preds: Sequence[Tensor], gt: Any, valid: Any = None, gamma: float = 0.8,
                  max_disp: float = 700.0) -> Tensor:
    """L = Σ_i gamma^(n-1-i) · mean_{valid} |d_i - d_gt| over the n predictions (a 0-d Tensor).

    Invalid ground truth is zeroed before the subtraction, so NaN/inf there never reaches the
    gradient; a prediction with no valid pixel contributes 0.

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
    n = len(preds)
    terms = [ops.masked_l1_loss(p, target, weight) * float(gamma ** (n - 1 - i)) for i, p in enumerate(preds)]
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
