"""pad: constant or replicate padding of the last two axes (kernels: ``pad2d_fwd`` / ``pad2d_bwd``)."""

from __future__ import annotations

from typing import Sequence

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["pad"]


class _Pad(Function):
    name = "pad"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, pad4, mode, value):
        # An unbatched (C, H, W) input runs as a batch of one.
        ctx.unbatched = x.ndim == 3
        x4 = x[None] if ctx.unbatched else x
        ctx.hw, ctx.pad4, ctx.mode = tuple(x4.shape[-2:]), pad4, mode
        y = _core.pad2d_fwd(x4, pad4, mode, value)
        return y[0] if ctx.unbatched else y

    @staticmethod
    def backward(ctx, g):
        dx = _core.pad2d_bwd(g[None] if ctx.unbatched else g, ctx.hw, ctx.pad4, ctx.mode)
        return (dx[0] if ctx.unbatched else dx), None, None, None


def pad(input: Tensor, pad: Sequence[int], mode: str = "constant", value: float | None = None) -> Tensor:
    """Pads the last two axes of ``input`` (``torch.nn.functional.pad``).

    Parameters
    ----------
    input : Tensor
        (N, C, H, W) or (C, H, W).
    pad : sequence of int
        torch's pad list, last axis first: ``[left, right]`` pads only W, ``[left, right, top, bottom]``
        pads W and H. Entries must be non-negative.
    mode : {"constant", "replicate"}
        Fill with ``value``, or repeat the nearest edge pixel.
    value : float, optional
        The fill of constant padding (default 0). Replicate padding takes no value.

    Shapes
    ------
    (N, C, H, W) -> (N, C, H + top + bottom, W + left + right).
    """
    x = as_tensor(input)
    pads = [int(p) for p in pad]
    if len(pads) not in (2, 4):
        raise ArgumentError(f"pad: pad must have 2 or 4 entries (only the last two axes can be padded), got {list(pad)}")
    if mode not in ("constant", "replicate"):
        raise ArgumentError(f"pad: unsupported mode {mode!r} (expected 'constant' or 'replicate')")
    if mode != "constant" and value not in (None, 0):
        raise ArgumentError(f"pad: padding mode {mode!r} doesn't take in value argument")
    return _Pad.apply(x, pads + [0] * (4 - len(pads)), mode, 0.0 if value is None else float(value))
