"""avg_pool2d (kernels: ``avg_pool2d_fwd`` / ``avg_pool2d_bwd``) and adaptive_avg_pool2d (via mean or avg_pool2d)."""

from __future__ import annotations

from typing import Any

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor, pair
from ._elementwise import mean

__all__ = ["avg_pool2d", "adaptive_avg_pool2d"]


class _AvgPool2d(Function):
    name = "avg_pool2d"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, geometry):
        ctx.shape, ctx.geometry = list(x.shape), geometry
        return _core.avg_pool2d_fwd(x, *geometry)

    @staticmethod
    def backward(ctx, g):
        return _core.avg_pool2d_bwd(g, ctx.shape, *ctx.geometry), None


def avg_pool2d(input: Tensor, kernel_size: Any, stride: Any = None, padding: Any = 0, ceil_mode: bool = False,
               count_include_pad: bool = True, divisor_override: int | None = None) -> Tensor:
    """Average pooling over the last two axes (``torch.nn.functional.avg_pool2d``).

    ``stride`` defaults to ``kernel_size``; ``padding`` (zeros, at most half the kernel) is counted in
    the divisor when ``count_include_pad``; ``divisor_override`` replaces the divisor.

    Shapes
    ------
    input: (N, C, H, W) or (C, H, W). Output: (.., OH, OW), OH = floor((H + 2*ph - kh) / sh) + 1
    (rounded up with ``ceil_mode``), OW likewise.
    """
    op = "avg_pool2d"
    k = pair(kernel_size, "kernel_size", op)
    s = k if stride is None or (isinstance(stride, (list, tuple)) and len(stride) == 0) else pair(stride, "stride", op)
    geometry = (k, s, pair(padding, "padding", op), bool(ceil_mode), bool(count_include_pad),
                None if divisor_override is None else int(divisor_override))
    return _AvgPool2d.apply(as_tensor(input), geometry)


def adaptive_avg_pool2d(input: Tensor, output_size: Any) -> Tensor:
    """Adaptive average pooling (``torch.nn.functional.adaptive_avg_pool2d``) for output sizes that
    divide the input: output 1 is ``mean(dim=(-2, -1), keepdim=True)`` (MIPNet's global pooling), other
    divisors ``avg_pool2d`` with kernel = stride = input / output. Other sizes raise ``ArgumentError``.

    Shapes
    ------
    input: (N, C, H, W) or (C, H, W). Output: (.., oh, ow).
    """
    op = "adaptive_avg_pool2d"
    x = as_tensor(input)
    if x.ndim not in (3, 4):
        from ..errors import ShapeError

        raise ShapeError(f"{op}: input must be a 3-D or 4-D tensor (got input={list(x.shape)})")
    h, w = x.shape[-2:]
    o = (output_size, output_size) if output_size is None or isinstance(output_size, int) else tuple(output_size)
    oh, ow = (h if o[0] is None else o[0]), (w if o[1] is None else o[1])
    if (oh, ow) == (1, 1):
        return mean(x, (-2, -1), keepdim=True)
    if oh < 1 or ow < 1 or h % oh or w % ow:
        raise ArgumentError(f"{op}: output_size {(oh, ow)} must divide the input size {(h, w)} (got input={list(x.shape)})")
    return avg_pool2d(x, (h // oh, w // ow))
