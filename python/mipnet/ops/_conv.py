"""2-D convolution, and convolution + ReLU fused (kernels: ``conv2d_fwd`` / ``conv2d_bwd``)."""

from __future__ import annotations

from .. import _core
from ..amp import bf16_active
from ..autograd import Function, is_grad_enabled
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor, pair

__all__ = ["conv2d", "conv2d_relu"]

#: Whether stride-1 float32 convolutions with 3x3, 1x5 or 5x1 kernels (forward, the input gradient,
#: itself such a convolution, and the weight gradient where the channels pay for it) use Winograd:
#: F(4x4, 3x3), 4x fewer multiplies, about 5-20x the rounding error of the direct convolution
#: (relative 5e-6 at 64 channels), and F(4, 5), 2.5x fewer, about 7x (1e-6). False: the direct
#: convolution. float64 always runs direct. Read at each call.
WINOGRAD = True


def reuse_kernels() -> bool:
    """Whether a forward convolution keeps its Winograd-transformed kernel for later calls with the
    same weight values: in a no-grad pass (inference), where weights stay fixed and the update block
    runs 6 + 6 times with the same ones; not while recording for a backward (training changes the
    weights every step, and the kept transforms would only hold memory)."""
    return not is_grad_enabled()


class _Conv2d(Function):
    name = "conv2d"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, weight, bias, stride, padding):
        ctx.save_for_backward(x, weight)
        ctx.stride, ctx.padding = stride, padding
        return _core.conv2d_fwd(x, weight, bias, stride, padding, winograd=WINOGRAD, reuse_kernels=reuse_kernels(),
                                bf16=bf16_active())

    @staticmethod
    def backward(ctx, g):
        x, weight = ctx.saved_tensors
        need_x, need_w, need_b = ctx.needs_input_grad[:3]
        dx, dw, db = _core.conv2d_bwd(x, weight, g, ctx.stride, ctx.padding, need_x, need_w, need_b, winograd=WINOGRAD)
        return dx, dw, db, None, None


class _Conv2dRelu(Function):
    """relu(conv2d(x, w, b)) with the ReLU in the GEMM's epilogue; the backward masks g by y > 0."""

    name = "conv2d_relu"

    @staticmethod
    def forward(ctx, x, weight, bias, stride, padding):
        y = _core.conv2d_fwd(x, weight, bias, stride, padding, relu=True, winograd=WINOGRAD,
                             reuse_kernels=reuse_kernels(), bf16=bf16_active())
        ctx.save_for_backward(x, weight, y)
        ctx.stride, ctx.padding = stride, padding
        return y

    @staticmethod
    def backward(ctx, g):
        x, weight, y = ctx.saved_tensors
        need_x, need_w, need_b = ctx.needs_input_grad[:3]
        # d relu: g · [y > 0], then the conv's backward
        g = _core.unary_bwd(y, g, "relu")
        dx, dw, db = _core.conv2d_bwd(x, weight, g, ctx.stride, ctx.padding, need_x, need_w, need_b, winograd=WINOGRAD)
        return dx, dw, db, None, None


def _conv_args(name: str, input, weight, bias, stride, padding, dilation, groups):
    """Validated arguments of conv2d / conv2d_relu: tensors, (sh, sw), (ph, pw)."""
    if pair(dilation, "dilation", name) != (1, 1):
        raise ArgumentError(f"{name}: only dilation=1 is supported, got dilation={dilation!r}")
    if groups != 1:
        raise ArgumentError(f"{name}: only groups=1 is supported, got groups={groups!r}")
    if isinstance(padding, str):
        if padding != "valid":
            raise ArgumentError(f"{name}: padding must be an int, a pair of ints or 'valid', got {padding!r}")
        padding = 0
    bias = None if bias is None else as_tensor(bias)
    return as_tensor(input), as_tensor(weight), bias, pair(stride, "stride", name), pair(padding, "padding", name)


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
    return _Conv2d.apply(*_conv_args("conv2d", input, weight, bias, stride, padding, dilation, groups))


def conv2d_relu(input: Tensor, weight: Tensor, bias: Tensor | None = None, stride=1, padding=0, dilation=1,
                groups=1) -> Tensor:
    """``relu(conv2d(input, weight, bias, stride, padding))`` in one kernel: the ReLU runs in the GEMM's
    epilogue, so the pre-activation is never written. Same result as the two ops (bitwise), same
    arguments, shapes and errors as :func:`conv2d`; its backward masks the gradient by output > 0."""
    return _Conv2dRelu.apply(*_conv_args("conv2d_relu", input, weight, bias, stride, padding, dilation, groups))
