"""Convex upsampling (RAFT; architecture.md §2.8), fused (kernels: ``convex_upsample_fwd`` / ``convex_upsample_bwd``)."""

from __future__ import annotations

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["convex_upsample"]


class _ConvexUpsample(Function):
    name = "convex_upsample"
    fresh_grads = True

    @staticmethod
    def forward(ctx, flow, mask, rate):
        ctx.save_for_backward(flow, mask)
        ctx.rate = rate
        return _core.convex_upsample_fwd(flow, mask, rate)

    @staticmethod
    def backward(ctx, g):
        flow, mask = ctx.saved_tensors
        dflow, dmask = _core.convex_upsample_bwd(flow, mask, g, ctx.rate)
        return dflow, dmask, None


def convex_upsample(flow: Tensor, mask: Tensor, rate: int = 4) -> Tensor:
    """Upsamples a field by ``rate`` with learned convex 3x3 combinations (RAFT ``upsample_flow``).

    ``out[d, R*y + i, R*x + j] = sum_k softmax_k(mask[k*R*R + i*R + j, y, x]) * R * flow[d, y + dy_k, x + dx_k]``
    with neighbour ``k = (dy+1)*3 + (dx+1)`` and flow read as 0 outside the map (unfold zero padding).

    Parameters
    ----------
    flow : Tensor
        (N, D, h, w), in the coarse level's pixel units.
    mask : Tensor
        (N, 9*R*R, h, w) logits.
    rate : int
        The factor R.

    Shapes
    ------
    flow (N, D, h, w), mask (N, 9·R², h, w) -> (N, D, R·h, R·w).
    """
    if int(rate) < 1:
        raise ArgumentError(f"convex_upsample: rate must be positive, got {rate}")
    f = as_tensor(flow)
    return _ConvexUpsample.apply(f, as_tensor(mask, f), int(rate))
