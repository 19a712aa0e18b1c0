"""The stereo correlations of MIPNet, fused (architecture.md §2.5, §2.6).

Kernels: ``ip_corr_fwd`` / ``ip_corr_bwd`` and ``rls_corr_fwd`` / ``rls_corr_bwd`` on already warped
maps (any flow), and ``ip_warp_corr_fwd`` / ``ip_warp_corr_bwd``, ``rls_warp_corr_fwd`` /
``rls_warp_corr_bwd`` with the warp inside, for a flow whose vertical component is zero.
"""

from __future__ import annotations

import numpy as np

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["ip_correlation", "rls_correlation", "ip_warp_correlation", "rls_warp_correlation", "IP_SEEDS"]

#: MIPNet's IP seed offsets (ox, oy) in stack order (architecture.md §2.5): centre, tl, tr, dl, dr.
IP_SEEDS = ((0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1))


class _IpCorr(Function):
    name = "ip_correlation"
    fresh_grads = True

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
    fresh_grads = True

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
    """Inverse-propagation correlation (architecture.md §2.5, semantic layout).

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
    """Rectangular-local-search correlation (architecture.md §2.6).

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


class _WarpCorr(Function):
    """Horizontal warp of F_R by the flow fused with a correlation; ``forward_kernel`` and
    ``backward_kernel`` take (fl, fr, flow_x[, g], *options)."""

    fresh_grads = True
    forward_kernel = backward_kernel = None

    @classmethod
    def forward(cls, ctx, fl, fr, flow_x, *options):
        ctx.save_for_backward(fl, fr, flow_x)
        ctx.options = options
        return cls.forward_kernel(fl, fr, flow_x, *options)

    @classmethod
    def backward(cls, ctx, g):
        fl, fr, flow_x = ctx.saved_tensors
        dfl, dfr = cls.backward_kernel(fl, fr, flow_x, g, *ctx.options)
        return (dfl, dfr, None) + (None,) * len(ctx.options)


class _IpWarpCorr(_WarpCorr):
    name = "ip_warp_correlation"
    forward_kernel, backward_kernel = staticmethod(_core.ip_warp_corr_fwd), staticmethod(_core.ip_warp_corr_bwd)


class _RlsWarpCorr(_WarpCorr):
    name = "rls_warp_correlation"
    forward_kernel, backward_kernel = staticmethod(_core.rls_warp_corr_fwd), staticmethod(_core.rls_warp_corr_bwd)


def _flow_x(flow_x, like: Tensor):
    """The horizontal flow as a C-contiguous array of ``like``'s dtype (it receives no gradient)."""
    a = flow_x.numpy() if isinstance(flow_x, Tensor) else np.asarray(flow_x)
    return np.ascontiguousarray(a, dtype=like.dtype)


def ip_warp_correlation(fl: Tensor, fr: Tensor, flow_x, groups: int = 2, seeds=IP_SEEDS) -> Tensor:
    """IP correlation of the seed stack warped by a horizontal flow, without building either (architecture.md §2.5).

    Equals ``ip_correlation(fl, grid_sample(stack(fr), grid(flow)))`` for the flow ``(flow_x, 0)``
    (border padding, align_corners=True) with ``stack`` the seed shifts ``S_s(y, x) = fr(clamp(y +
    oy), clamp(x + ox))``: output channel ``S*g + s`` is the mean over group g's channels of ``fl``
    times the warped seed s. The flow gets no gradient.

    Parameters
    ----------
    fl, fr : Tensor
        Left and right features, channels-last (N, h, w, C).
    flow_x : array or Tensor
        Horizontal flow (N, h, w) in pixels of the level (``-disparity``).
    groups : int
        Channel groups G; C must be divisible by G.
    seeds : sequence of (ox, oy)
        Seed offsets in stack order (default: MIPNet's five).

    Shapes
    ------
    fl, fr (N, h, w, C), flow_x (N, h, w) -> (N, G·S, h, w).
    """
    if int(groups) < 1:
        raise ArgumentError(f"ip_warp_correlation: groups must be positive, got {groups}")
    f = as_tensor(fl)
    return _IpWarpCorr.apply(f, as_tensor(fr, f), _flow_x(flow_x, f), int(groups),
                             [(int(ox), int(oy)) for ox, oy in seeds])


def rls_warp_correlation(fl: Tensor, fr: Tensor, flow_x, rx: int = 3, ry: int = 1) -> Tensor:
    """RLS correlation of the right features warped by a horizontal flow, without building the warped
    map (architecture.md §2.6).

    Equals ``rls_correlation(fl, grid_sample(fr, grid(flow)), rx, ry)`` for the flow ``(flow_x, 0)``
    (border padding, align_corners=True). The flow gets no gradient.

    Parameters
    ----------
    fl, fr : Tensor
        Left and right features, channels-last (N, h, w, C).
    flow_x : array or Tensor
        Horizontal flow (N, h, w) in pixels of the level.
    rx, ry : int
        Horizontal and vertical search radii.

    Shapes
    ------
    fl, fr (N, h, w, C), flow_x (N, h, w) -> (N, (2rx+1)(2ry+1), h, w).
    """
    if int(rx) < 0 or int(ry) < 0:
        raise ArgumentError(f"rls_warp_correlation: rx and ry must be non-negative, got rx={rx}, ry={ry}")
    f = as_tensor(fl)
    return _RlsWarpCorr.apply(f, as_tensor(fr, f), _flow_x(flow_x, f), int(rx), int(ry))
