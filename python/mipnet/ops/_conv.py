"""2-D convolution (kernels: ``conv2d_fwd`` / ``conv2d_bwd``)."""

from __future__ import annotations

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor, pair

__all__ = ["conv2d"]


class _Conv2d(Function):
    name = "conv2d"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, weight, bias, stride, padding):
        ctx.save_for_backward(x, weight)
        ctx.stride, ctx.padding = stride, padding
        return _core.conv2d_fwd(x, weight, bias, stride, padding)

    @staticmethod
    def backward(ctx, g):
        x, weight = ctx.saved_tensors
        need_x, need_w, need_b = ctx.needs_input_grad[:3]
        dx, dw, db = _core.conv2d_bwd(x, weight, g, ctx.stride, ctx.padding, need_x, need_w, need_b)
        return dx, dw, db, None, None


def conv2d(input: Tensor, weight: Tensor, bias: Tensor | None = None, stride=1, padding=0, dilation=1,
           groups=1) -> Tensor:
    """2-D convolution (cross-correlation) with zero padding, as ``torch.nn.functional.conv2d``.

    Parameters
    ----------
    input : Tensor
        The batch of images.
    weight : Tensor
        The filters.
    bias : Tensor, optional
        One value per output channel.
    stride : int or (int, int)
        Step between output pixels, per axis (>= 1).
    padding : int or (int, int) or "valid"
        Zeros added on both sides of each axis (>= 0); "valid" means 0.
    dilation : int or (int, int)
        Only 1 is supported.
    groups : int
        Only 1 is supported.

    Shapes
    ------
    input (N, Cin, H, W), weight (Cout, Cin, kh, kw), bias (Cout,) -> (N, Cout, Ho, Wo) with
    Ho = (H + 2 * ph - kh) // sh + 1 and Wo = (W + 2 * pw - kw) // sw + 1.

    Raises
    ------
    ArgumentError
        dilation or groups other than 1, a string padding other than "valid", stride < 1, padding < 0.
    ShapeError
        wrong ranks, channel mismatch, empty tensors, a kernel larger than the padded input.
    """
    if pair(dilation, "dilation", "conv2d") != (1, 1):
        raise ArgumentError(f"conv2d: only dilation=1 is supported, got dilation={dilation!r}")
    if groups != 1:
        raise ArgumentError(f"conv2d: only groups=1 is supported, got groups={groups!r}")
    if isinstance(padding, str):
        if padding != "valid":
            raise ArgumentError(f"conv2d: padding must be an int, a pair of ints or 'valid', got {padding!r}")
        padding = 0
    input = as_tensor(input)
    weight = as_tensor(weight)
    bias = None if bias is None else as_tensor(bias)
    return _Conv2d.apply(input, weight, bias, pair(stride, "stride", "conv2d"), pair(padding, "padding", "conv2d"))
