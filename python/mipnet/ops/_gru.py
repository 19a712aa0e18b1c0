"""The gate arithmetic of a convolutional GRU step, fused (kernels: ``gru_reset_fwd`` / ``gru_reset_bwd``,
``gru_update_fwd`` / ``gru_update_bwd``; architecture.md §2.7).

One step is ``zr = conv(hx)`` (z and r from one convolution), ``q = gru_candidate(zr, hx, Wq, bq)``
(= ``conv(gru_reset(zr, hx))``), ``h' = gru_update(zr, q, hx)``, with ``hx = cat[h, x]``.
"""

from __future__ import annotations

from .. import _core
from ..amp import bf16_active
from ..autograd import Function
from ..tensor import Tensor
from ._common import as_tensor, pair
from . import _conv

__all__ = ["gru_reset", "gru_candidate", "gru_update"]


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


class _GruCandidate(Function):
    """conv2d(gru_reset(zr, hx), w, b): the candidate's convolution on [r h, x]. [r h, x] is not kept
    for the backward (it is as large as hx): the backward rebuilds it from zr and hx, which the gates
    keep anyway, with one element-wise pass."""

    name = "gru_candidate"
    fresh_grads = True

    @staticmethod
    def forward(ctx, zr, hx, weight, bias, padding):
        ctx.save_for_backward(zr, hx, weight)
        ctx.padding = padding
        return _core.conv2d_fwd(_core.gru_reset_fwd(zr, hx), weight, bias, (1, 1), padding, winograd=_conv.WINOGRAD,
                                reuse_kernels=_conv.reuse_kernels(), bf16=bf16_active())

    @staticmethod
    def backward(ctx, g):
        zr, hx, weight = ctx.saved_tensors
        need_zr, need_hx, need_w, need_b = ctx.needs_input_grad[:4]
        need_gates = need_zr or need_hx
        rhx = _core.gru_reset_fwd(zr, hx)
        drhx, dw, db = _core.conv2d_bwd(rhx, weight, g, (1, 1), ctx.padding, need_gates, need_w, need_b,
                                        winograd=_conv.WINOGRAD)
        del rhx  # freed before the gates' backward allocates their gradients
        dzr, dhx = _core.gru_reset_bwd(zr, hx, drhx) if need_gates else (None, None)
        return dzr, dhx, dw, db, None


def gru_candidate(zr: Tensor, hx: Tensor, weight: Tensor, bias: Tensor | None = None, padding=0) -> Tensor:
    """``conv2d(gru_reset(zr, hx), weight, bias, stride=1, padding=padding)``: the GRU's candidate
    pre-activation, without keeping ``[r h, x]`` for the backward.

    Shapes
    ------
    zr (N, 2H, h, w), hx (N, H + X, h, w), weight (C, H + X, kh, kw) -> (N, C, h + 2 ph - kh + 1, w + 2 pw - kw + 1).
    """
    z = as_tensor(zr)
    b = None if bias is None else as_tensor(bias, z)
    return _GruCandidate.apply(z, as_tensor(hx, z), as_tensor(weight, z), b, pair(padding, "padding", "gru_candidate"))


def gru_update(zr: Tensor, q: Tensor, hx: Tensor, keep_x: bool = False) -> Tensor:
    """``(1 - z) * h + z * tanh(q)`` with ``z = sigmoid(zr[:, :H])``, ``h = hx[:, :H]``; with ``keep_x``
    followed by ``x = hx[:, H:]`` along the channels (the next pass's ``[h', x]``).

    Shapes
    ------
    zr (N, 2H, h, w), q (N, H, h, w), hx (N, H + X, h, w) -> (N, H, h, w), or (N, H + X, h, w) with keep_x.
    """
    z = as_tensor(zr)
    return _GruUpdate.apply(z, as_tensor(q, z), as_tensor(hx, z), bool(keep_x))
