"""The stereo correlations of MIPNet, fused (kernels: ``ip_corr_fwd`` / ``ip_corr_bwd``,
``rls_corr_fwd`` / ``rls_corr_bwd``; spec a.6, a.7)."""

from __future__ import annotations

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["ip_correlation", "rls_correlation"]


class _IpCorr(Function):
    name = "ip_correlation"

    @staticmethod
    def forward(ctx, fl, stack, groups):
        ctx.save_for_backward(fl, stack)
        ctx.groups = groups
        return _core.ip_corr_fwd(fl, stack, groups)

    @staticmethod
    def backward(ctx, g):
        fl, stack = ctx.saved_tensors
        dfl, dstack = _core.ip_corr_bwd(fl, stack, g, ctx.groups)
        return dfl, dstack, None


class _RlsCorr(Function):
    name = "rls_correlation"

    @staticmethod
    def forward(ctx, fl, warped, rx, ry):
        ctx.save_for_backward(fl, warped)
        ctx.rx, ctx.ry = rx, ry
        return _core.rls_corr_fwd(fl, warped, rx, ry)

    @staticmethod
    def backward(ctx, g):
        fl, warped = ctx.saved_tensors
        dfl, dwarped = _core.rls_corr_bwd(fl, warped, g, ctx.rx, ctx.ry)
        return dfl, dwarped, None, None


def ip_correlation(fl: Tensor, stack: Tensor, groups: int = 2) -> Tensor:
    """Inverse-propagation correlation (spec a.6, semantic layout).

    Output channel ``S*g + s`` is the mean over the C/G channels k of group g of
    ``fl[g*C/G + k] * stack[s*C + g*C/G + k]``; the number of seeds S is ``stack.shape[1] // C``.

    Parameters
    ----------
    fl : Tensor
        Left features (N, C, h, w).
    stack : Tensor
        The warped seed stack (N, S*C, h, w), seed s in channels ``s*C .. (s+1)*C``.
    groups : int
        Channel groups G; C must be divisible by G.

    Shapes
    ------
    fl (N, C, h, w), stack (N, S·C, h, w) -> (N, G·S, h, w).
    """
    if int(groups) < 1:
        raise ArgumentError(f"ip_correlation: groups must be positive, got {groups}")
    f = as_tensor(fl)
    return _IpCorr.apply(f, as_tensor(stack, f), int(groups))


def rls_correlation(fl: Tensor, warped: Tensor, rx: int = 3, ry: int = 1) -> Tensor:
    """Rectangular-local-search correlation (spec a.7).

    With P the replicate padding of ``warped`` by [rx, rx, ry, ry], output channel ``(2*ry+1)*i + j``
    (x shift outer, y shift inner) is the channel mean of ``fl * P[:, :, j:j+h, i:i+w]``; P is never built.

    Parameters
    ----------
    fl : Tensor
        Left features (N, C, h, w).
    warped : Tensor
        Warped right features (N, C, h, w).
    rx, ry : int
        Horizontal and vertical search radii.

    Shapes
    ------
    fl, warped (N, C, h, w) -> (N, (2rx+1)(2ry+1), h, w).
    """
    if int(rx) < 0 or int(ry) < 0:
        raise ArgumentError(f"rls_correlation: rx and ry must be non-negative, got rx={rx}, ry={ry}")
    f = as_tensor(fl)
    return _RlsCorr.apply(f, as_tensor(warped, f), int(rx), int(ry))
