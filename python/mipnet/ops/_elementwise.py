"""add, sub, mul with broadcasting; mean and sum over axes; dtype casts."""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np

from .. import _core
from ..autograd import Function
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["add", "sub", "mul", "mean", "sum", "to_dtype"]


class _Binary(Function):
    @staticmethod
    def forward(ctx, a, b, op):
        ctx.op = op
        # only mul reads the operands in backward; add/sub keep nothing alive (the tape's memory)
        if op == "mul":
            ctx.save_for_backward(a, b)
        return _core.binary_fwd(a, b, op)

    @staticmethod
    def backward(ctx, g):
        if ctx.op == "mul":
            a, b = ctx.saved_tensors
            ga, gb = _core.binary_bwd(a, b, g, "mul")
            return ga, gb, None
        # d(a ± b) = (g, ±g); the engine sums each back to its input's shape
        return g, (g if ctx.op == "add" else _core.affine_fwd(g, -1.0, 0.0)), None


#: One Function class per binary op, so errors name the op (add/sub pass g itself on: not fresh).
_BINARY = {op: type(f"_{op.title()}", (_Binary,), {"name": op, "fresh_grads": op == "mul"}) for op in ("add", "sub", "mul")}


class _Affine(Function):
    name = "affine"
    fresh_grads = True
    @staticmethod
    def forward(ctx, x, alpha, beta):
        ctx.alpha = alpha
        return _core.affine_fwd(x, alpha, beta)

    @staticmethod
    def backward(ctx, g):
        # d(alpha*x + beta)/dx = alpha
        return _core.affine_fwd(g, ctx.alpha, 0.0), None, None


def _binary(a: Any, b: Any, op: str) -> Tensor:
    """Tensor ∘ scalar becomes one affine op; anything else the broadcasting binary kernel."""
    if np.isscalar(b) and isinstance(a, Tensor):
        alpha, beta = {"add": (1.0, float(b)), "sub": (1.0, -float(b)), "mul": (float(b), 0.0)}[op]
        return _Affine.apply(a, alpha, beta)
    if np.isscalar(a) and isinstance(b, Tensor):
        alpha, beta = {"add": (1.0, float(a)), "sub": (-1.0, float(a)), "mul": (float(a), 0.0)}[op]
        return _Affine.apply(b, alpha, beta)
    like = a if isinstance(a, Tensor) else b if isinstance(b, Tensor) else None
    return _BINARY[op].apply(as_tensor(a, like), as_tensor(b, like), op)


def add(input: Any, other: Any) -> Tensor:
    """input + other, broadcasting."""
    return _binary(input, other, "add")


def sub(input: Any, other: Any) -> Tensor:
    """input - other, broadcasting."""
    return _binary(input, other, "sub")


def mul(input: Any, other: Any) -> Tensor:
    """input * other, broadcasting."""
    return _binary(input, other, "mul")


def _axes(dim: int | Iterable[int] | None, ndim: int) -> list[int]:
    dims = range(ndim) if dim is None else [dim] if isinstance(dim, (int, np.integer)) else list(dim)
    return sorted(int(d) % ndim if ndim else int(d) for d in dims)


class _Mean(Function):
    name = "mean"
    fresh_grads = True
    @staticmethod
    def forward(ctx, x, axes, keepdim):
        ctx.shape, ctx.axes = list(x.shape), axes
        return _core.mean_fwd(x, axes, keepdim)

    @staticmethod
    def backward(ctx, g):
        return _core.mean_bwd(g, ctx.shape, ctx.axes), None, None


def mean(input: Tensor, dim: int | Iterable[int] | None = None, keepdim: bool = False) -> Tensor:
    """Mean over ``dim`` (all axes if None), as ``torch.mean``."""
    x = as_tensor(input)
    return _Mean.apply(x, _axes(dim, x.ndim), keepdim)


def sum(input: Tensor, dim: int | Iterable[int] | None = None, keepdim: bool = False) -> Tensor:
    """Sum over ``dim`` (all axes if None): the mean times the number of reduced elements."""
    x = as_tensor(input)
    axes = _axes(dim, x.ndim)
    count = int(np.prod([x.shape[a] for a in axes])) if axes else 1
    return mul(_Mean.apply(x, axes, keepdim), float(count))


class _Cast(Function):
    name = "to_dtype"
    fresh_grads = True
    @staticmethod
    def forward(ctx, x, dtype):
        ctx.src = x.dtype
        return x.astype(dtype)

    @staticmethod
    def backward(ctx, g):
        return g.astype(ctx.src), None


def to_dtype(input: Tensor, dtype: Any) -> Tensor:
    """The values as float32 or float64 (differentiable)."""
    x = as_tensor(input)
    dtype = np.dtype(dtype)
    if x.dtype == dtype:
        return x
    from ..tensor import _as_float_array

    _as_float_array(np.zeros(0), dtype)  # validates dtype (raises DTypeError otherwise)
    return _Cast.apply(x, dtype)
