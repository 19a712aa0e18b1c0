"""relu, sigmoid, tanh (kernels: ``unary_fwd`` / ``unary_bwd``; backward from the output)."""

from __future__ import annotations

from .. import _core
from ..autograd import Function
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["relu", "sigmoid", "tanh"]


class _Unary(Function):
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, act):
        y = _core.unary_fwd(x, act)
        ctx.save_for_backward(y)
        ctx.act = act
        return y

    @staticmethod
    def backward(ctx, g):
        (y,) = ctx.saved_tensors
        return _core.unary_bwd(y, g, ctx.act), None


_UNARY = {act: type(f"_{act.title()}", (_Unary,), {"name": act}) for act in ("relu", "sigmoid", "tanh")}


def relu(input: Tensor, inplace: bool = False) -> Tensor:
    """max(x, 0). ``inplace`` is accepted for torch compatibility and ignored."""
    return _UNARY["relu"].apply(as_tensor(input), "relu")


def sigmoid(input: Tensor) -> Tensor:
    """1 / (1 + exp(-x))."""
    return _UNARY["sigmoid"].apply(as_tensor(input), "sigmoid")


def tanh(input: Tensor) -> Tensor:
    """tanh(x)."""
    return _UNARY["tanh"].apply(as_tensor(input), "tanh")
