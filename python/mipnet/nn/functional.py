"""Functions with ``torch.nn.functional``'s names and argument names, over :mod:`mipnet.ops`.

``import mipnet.nn.functional as F`` then ``F.conv2d``, ``F.relu``, ``F.interpolate``... as in torch. Most
are mipnet's ops themselves (each op documents the arguments it supports: e.g. ``conv2d`` only with
``dilation=1, groups=1``, ``interpolate`` and ``grid_sample`` only bilinear); the activations and losses
that mipnet has no kernel for (``leaky_relu``, ``hardtanh``, ``relu6``, ``silu``, ``l1_loss``,
``mse_loss``, ``smooth_l1_loss``, ``huber_loss``) are compositions of ops, differentiable through them.
"""

from __future__ import annotations

from typing import Any

from .. import ops
from ..errors import ArgumentError
from ..ops import (adaptive_avg_pool2d, avg_pool2d, batch_norm, conv2d, fold, grid_sample, instance_norm,
                   interpolate, pad, relu, sigmoid, softmax, tanh, unfold)
from ..ops._common import as_tensor
from ..tensor import Tensor

__all__ = [
    # convolution, pooling, resampling
    "conv2d", "avg_pool2d", "adaptive_avg_pool2d", "pad", "interpolate", "grid_sample", "unfold", "fold",
    # normalisation
    "batch_norm", "instance_norm",
    # activations
    "relu", "sigmoid", "tanh", "softmax", "leaky_relu", "hardtanh", "relu6", "silu",
    # losses
    "l1_loss", "mse_loss", "smooth_l1_loss", "huber_loss",
]


def __dir__() -> list[str]:
    return sorted(__all__)


# ---------------------------------------------------------------------------------- activations

def leaky_relu(input: Tensor, negative_slope: float = 0.01, inplace: bool = False) -> Tensor:
    """x where x > 0, ``negative_slope * x`` elsewhere (``torch.nn.functional.leaky_relu``), computed as
    ``negative_slope * x + (1 - negative_slope) * relu(x)``. ``inplace`` is accepted and ignored.

    Shapes
    ------
    any shape -> the same shape.
    """
    x = as_tensor(input)
    s = float(negative_slope)
    return ops.add(ops.mul(x, s), ops.mul(relu(x), 1.0 - s))


def hardtanh(input: Tensor, min_val: float = -1.0, max_val: float = 1.0, inplace: bool = False) -> Tensor:
    """x clamped to [min_val, max_val] (``torch.nn.functional.hardtanh``), computed as
    ``min_val + relu(x - min_val) - relu(x - max_val)``. ``inplace`` is accepted and ignored.

    Shapes
    ------
    any shape -> the same shape.
    """
    lo, hi = float(min_val), float(max_val)
    if hi < lo:
        raise ArgumentError(f"hardtanh: max_val ({max_val}) must not be less than min_val ({min_val})")
    x = as_tensor(input)
    return ops.add(ops.sub(relu(ops.sub(x, lo)), relu(ops.sub(x, hi))), lo)


def relu6(input: Tensor, inplace: bool = False) -> Tensor:
    """min(max(x, 0), 6) (``torch.nn.functional.relu6``). ``inplace`` is accepted and ignored."""
    return hardtanh(input, 0.0, 6.0)


def silu(input: Tensor, inplace: bool = False) -> Tensor:
    """x * sigmoid(x), the swish (``torch.nn.functional.silu``). ``inplace`` is accepted and ignored."""
    x = as_tensor(input)
    return ops.mul(x, sigmoid(x))


# --------------------------------------------------------------------------------------- losses

def _reduce(loss: Tensor, reduction: str, name: str) -> Tensor:
    if reduction == "mean":
        return ops.mean(loss)
    if reduction == "sum":
        return ops.sum(loss)
    if reduction == "none":
        return loss
    raise ArgumentError(f"{name}: reduction must be 'mean', 'sum' or 'none', got {reduction!r}")


def _difference(input: Any, target: Any) -> Tensor:
    x = as_tensor(input)
    return ops.sub(x, as_tensor(target, x))


def _abs(d: Tensor) -> Tensor:
    return ops.add(relu(d), relu(ops.mul(d, -1.0)))


def l1_loss(input: Tensor, target: Any, *, reduction: str = "mean") -> Tensor:
    """|input - target|, reduced (``torch.nn.functional.l1_loss``). Both operands get gradients.

    Parameters
    ----------
    input, target : Tensor or array_like
        Broadcast against each other.
    reduction : {"mean", "sum", "none"}

    Shapes
    ------
    input, target: any (broadcastable) shapes. Output: 0-d, or their broadcast shape for "none".
    """
    return _reduce(_abs(_difference(input, target)), reduction, "l1_loss")


def mse_loss(input: Tensor, target: Any, *, reduction: str = "mean") -> Tensor:
    """(input - target)^2, reduced (``torch.nn.functional.mse_loss``); ``reduction`` as :func:`l1_loss`."""
    d = _difference(input, target)
    return _reduce(ops.mul(d, d), reduction, "mse_loss")


def _smooth(d: Tensor, beta: float) -> Tensor:
    """0.5 d^2 / beta where |d| < beta, |d| - 0.5 beta elsewhere: with m = min(|d|, beta) = |d| - relu(|d| - beta),
    0.5 m^2 / beta + (|d| - m)."""
    a = _abs(d)
    excess = relu(ops.sub(a, beta))
    m = ops.sub(a, excess)
    return ops.add(ops.mul(ops.mul(m, m), 0.5 / beta), excess)


def smooth_l1_loss(input: Tensor, target: Any, *, reduction: str = "mean", beta: float = 1.0) -> Tensor:
    """Smooth L1 (``torch.nn.functional.smooth_l1_loss``): 0.5 d^2 / beta where |d| < beta, else
    |d| - 0.5 beta, for d = input - target; ``beta=0`` is the L1 loss. ``reduction`` as :func:`l1_loss`."""
    if beta < 0:
        raise ArgumentError(f"smooth_l1_loss: beta must be non-negative, got {beta}")
    d = _difference(input, target)
    return _reduce(_abs(d) if beta == 0 else _smooth(d, float(beta)), reduction, "smooth_l1_loss")


def huber_loss(input: Tensor, target: Any, *, reduction: str = "mean", delta: float = 1.0) -> Tensor:
    """Huber (``torch.nn.functional.huber_loss``): 0.5 d^2 where |d| < delta, else delta (|d| - 0.5 delta),
    i.e. ``delta * smooth_l1_loss(beta=delta)``. ``reduction`` as :func:`l1_loss`."""
    if delta <= 0:
        raise ArgumentError(f"huber_loss: delta must be positive, got {delta}")
    d = _difference(input, target)
    return _reduce(ops.mul(_smooth(d, float(delta)), float(delta)), reduction, "huber_loss")
