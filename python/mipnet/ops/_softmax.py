"""softmax along one dim (kernels: ``softmax_fwd`` / ``softmax_bwd``; backward from the output)."""

from __future__ import annotations

from typing import Any

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor
from ._elementwise import to_dtype

__all__ = ["softmax"]


class _Softmax(Function):
    name = "softmax"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, dim):
        y = _core.softmax_fwd(x, dim)
        ctx.save_for_backward(y)
        ctx.dim = dim
        return y

    @staticmethod
    def backward(ctx, g):
        (y,) = ctx.saved_tensors
        return _core.softmax_bwd(y, g, ctx.dim), None


def softmax(input: Tensor, dim: int | None = None, _stacklevel: int = 3, dtype: Any = None) -> Tensor:
    """exp(x) / sum(exp(x)) along ``dim`` (negative dims count from the end), computed with the
    maximum subtracted (``torch.nn.functional.softmax``; also ``torch.softmax(input, dim)``).
    ``dtype`` casts the input first; the implicit ``dim=None`` of old torch is not supported.

    Shapes
    ------
    input: any shape. Output: the same shape.
    """
    if dim is None:
        raise ArgumentError("softmax: dim must be given (implicit dim choice is not supported)")
    x = as_tensor(input)
    if dtype is not None:
        x = to_dtype(x, dtype)
    return _Softmax.apply(x, int(dim))
