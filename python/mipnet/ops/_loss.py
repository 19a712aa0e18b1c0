"""masked_l1_loss: MIPNet's per-prediction sequence-loss term (kernels: ``masked_l1_fwd`` / ``masked_l1_bwd``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _core
from ..autograd import Function
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["masked_l1_loss"]


class _MaskedL1(Function):
    name = "masked_l1_loss"
    fresh_grads = True

    @staticmethod
    def forward(ctx, pred, target, valid):
        ctx.save_for_backward(pred, target, valid)
        return _core.masked_l1_fwd(pred, target, valid)

    @staticmethod
    def backward(ctx, g):
        pred, target, valid = ctx.saved_tensors
        # g holds one value (0-d, or 1-d after Tensor.backward's np.ascontiguousarray)
        return _core.masked_l1_bwd(pred, target, valid, np.asarray(g).item()), None, None


def _data(a: Any) -> Any:
    return a.data if isinstance(a, Tensor) else a


def masked_l1_loss(input: Tensor, target: Any, valid: Any) -> Tensor:
    """Mean of |input - target| over the positions where ``valid`` holds (bool, or float >= 0.5):
    ``(input - target).abs()[valid].mean()`` in torch, except that no valid position gives 0, not NaN.
    ``target`` at invalid positions is never read, so it may hold NaN or inf. ``target`` and ``valid``
    receive no gradient; the gradient of ``input`` is sign(input - target) / #valid at valid positions
    (0 where input == target) and 0 elsewhere.

    Shapes
    ------
    input, target, valid: one shape. Output: a 0-d tensor.
    """
    x = as_tensor(input)
    mask = np.asarray(_data(valid))
    if mask.dtype != x.dtype:
        mask = mask.astype(x.dtype)
    return _MaskedL1.apply(x, _data(target), mask)
