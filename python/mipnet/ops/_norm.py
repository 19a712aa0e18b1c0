"""instance_norm and batch_norm (kernels: ``instance_norm_fwd/bwd``, ``batch_norm_fwd/bwd``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["instance_norm", "batch_norm"]


def _affine_grads(ctx, dw, db) -> tuple:
    """dweight / dbias where the op had that parameter and it needs a gradient, else None."""
    _, nw, nb = ctx.needs_input_grad[:3]
    return (dw if nw else None), (db if nb else None)


class _InstanceNorm(Function):
    name = "instance_norm"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, weight, bias, eps):
        y, mean, invstd = _core.instance_norm_fwd(x, weight, bias, eps)
        ctx.save_for_backward(x, mean, invstd, weight)
        return y

    @staticmethod
    def backward(ctx, g):
        x, mean, invstd, weight = ctx.saved_tensors
        dx, dw, db = _core.instance_norm_bwd(x, mean, invstd, g, weight)
        return (dx, *_affine_grads(ctx, dw, db), None)


class _BatchNorm(Function):
    name = "batch_norm"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, weight, bias, running_mean, running_var, training, momentum, eps):
        y, mean, invstd, new_mean, new_var = _core.batch_norm_fwd(
            x, weight, bias, running_mean, running_var, training, momentum, eps)
        if new_mean is not None:
            # torch updates the caller's running statistics in place
            running_mean[...] = new_mean
            running_var[...] = new_var
        ctx.save_for_backward(x, mean, invstd, weight)
        ctx.training = training
        return y

    @staticmethod
    def backward(ctx, g):
        x, mean, invstd, weight = ctx.saved_tensors
        dx, dw, db = _core.batch_norm_bwd(x, mean, invstd, g, weight, ctx.training)
        return (dx, *_affine_grads(ctx, dw, db), None, None, None, None, None)


def _param(p: Any, like: Tensor) -> Tensor | None:
    return None if p is None else as_tensor(p, like)


def _stat_array(s: Any, name: str) -> np.ndarray | None:
    """The array a running statistic is read from and updated in (a Tensor's ``.data`` or an ndarray)."""
    if s is None:
        return None
    if isinstance(s, Tensor):
        return s.data
    if isinstance(s, np.ndarray):
        return s
    raise ArgumentError(f"batch_norm: {name} must be a Tensor, a numpy array or None, got {type(s).__name__}")


def instance_norm(input: Tensor, running_mean: Any = None, running_var: Any = None, weight: Any = None,
                  bias: Any = None, use_input_stats: bool = True, momentum: float = 0.1, eps: float = 1e-5) -> Tensor:
    """Instance normalisation: each (n, c) plane minus its mean, divided by sqrt(biased var + eps),
    then ``* weight[c] + bias[c]`` when given (``torch.nn.functional.instance_norm``).

    Running statistics (``running_mean``/``running_var``, ``use_input_stats=False``) are not supported.

    Shapes
    ------
    input: (N, C, H, W) with H*W > 1; weight, bias: (C,). Output: (N, C, H, W).
    """
    if running_mean is not None or running_var is not None or not use_input_stats:
        raise ArgumentError("instance_norm: running statistics (running_mean, running_var, use_input_stats=False) are not supported")
    x = as_tensor(input)
    return _InstanceNorm.apply(x, _param(weight, x), _param(bias, x), float(eps))


def batch_norm(input: Tensor, running_mean: Any, running_var: Any, weight: Any = None, bias: Any = None,
               training: bool = False, momentum: float = 0.1, eps: float = 1e-5) -> Tensor:
    """Batch normalisation (``torch.nn.functional.batch_norm``).

    Training: each channel is normalised with the mean and biased variance over (N, H, W); when given,
    ``running_mean``/``running_var`` (Tensors or numpy arrays) are updated in place with
    ``(1 - momentum) * running + momentum * batch_stat`` using the unbiased variance. Eval: the running
    statistics normalise and are required. Then ``* weight[c] + bias[c]`` when given.

    Shapes
    ------
    input: (N, C, H, W) (training needs N*H*W > 1); running_mean, running_var, weight, bias: (C,).
    Output: (N, C, H, W).
    """
    if momentum is None:
        raise ArgumentError("batch_norm: momentum=None (cumulative moving average) is not supported")
    x = as_tensor(input)
    rm, rv = _stat_array(running_mean, "running_mean"), _stat_array(running_var, "running_var")
    return _BatchNorm.apply(x, _param(weight, x), _param(bias, x), rm, rv, bool(training), float(momentum), float(eps))
