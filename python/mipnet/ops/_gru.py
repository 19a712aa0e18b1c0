"""The gate arithmetic of a convolutional GRU step, fused (kernels: ``gru_reset_fwd`` / ``gru_reset_bwd``,
``gru_update_fwd`` / ``gru_update_bwd``; spec a.8).

One step is ``zr = conv(hx)`` (z and r from one convolution), ``rhx = gru_reset(zr, hx)``,
``q = conv(rhx)``, ``h' = gru_update(zr, q, hx)``, with ``hx = cat[h, x]``.
"""

from __future__ import annotations

from .. import _core
from ..autograd import Function
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["gru_reset", "gru_update"]


class _GruReset(Function):
    name = "gru_reset"
    fresh_grads = True

    @staticmethod
    def forward(ctx, zr, hx):
        ctx.save_for_backward(zr, hx)
        return _core.gru_reset_fwd(zr, hx)

    @staticmethod
    def backward(ctx, g):
        zr, hx = ctx.saved_tensors
        return _core.gru_reset_bwd(zr, hx, g)


class _GruUpdate(Function):
    name = "gru_update"
    fresh_grads = True

    @staticmethod
    def forward(ctx, zr, q, hx, keep_x):
        ctx.save_for_backward(zr, q, hx)
        ctx.keep_x = keep_x
        return _core.gru_update_fwd(zr, q, hx, keep_x)

    @staticmethod
    def backward(ctx, g):
        zr, q, hx = ctx.saved_tensors
        return (*_core.gru_update_bwd(zr, q, hx, g, ctx.keep_x), None)


def gru_reset(zr: Tensor, hx: Tensor) -> Tensor:
    """``cat([sigmoid(zr[:, H:]) * hx[:, :H], hx[:, H:]], 1)``: the input of the candidate's convolution.

    Shapes
    ------
    zr (N, 2H, h, w) (z then r pre-activations), hx (N, H + X, h, w) -> (N, H + X, h, w).
    """
    z = as_tensor(zr)
    return _GruReset.apply(z, as_tensor(hx, z))


def gru_update(zr: Tensor, q: Tensor, hx: Tensor, keep_x: bool = False) -> Tensor:
    """``(1 - z) * h + z * tanh(q)`` with ``z = sigmoid(zr[:, :H])``, ``h = hx[:, :H]``; with ``keep_x``
    followed by ``x = hx[:, H:]`` along the channels (the next pass's ``[h', x]``).

    Shapes
    ------
    zr (N, 2H, h, w), q (N, H, h, w), hx (N, H + X, h, w) -> (N, H, h, w), or (N, H + X, h, w) with keep_x.
    """
    z = as_tensor(zr)
    return _GruUpdate.apply(z, as_tensor(q, z), as_tensor(hx, z), bool(keep_x))
