"""iAFF's attentional gate, fused (kernels: ``attention_gate_fwd`` / ``attention_gate_bwd``; architecture.md §2.2)."""

from __future__ import annotations

from .. import _core
from ..autograd import Function
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["attention_gate"]


class _AttentionGate(Function):
    name = "attention_gate"
    fresh_grads = True

    @staticmethod
    def forward(ctx, local, glob, x, y):
        ctx.save_for_backward(local, glob, x, y)
        return _core.attention_gate_fwd(local, glob, x, y)

    @staticmethod
    def backward(ctx, g):
        return _core.attention_gate_bwd(*ctx.saved_tensors, g)


def attention_gate(local: Tensor, glob: Tensor, x: Tensor, y: Tensor) -> Tensor:
    """``w * x + (1 - w) * y`` with ``w = sigmoid(local + glob)``: MS-CAM's weights applied as iAFF's gate.

    Shapes
    ------
    local, x, y (N, C, H, W), glob (N, C, 1, 1) -> (N, C, H, W).
    """
    t = as_tensor(local)
    return _AttentionGate.apply(t, as_tensor(glob, t), as_tensor(x, t), as_tensor(y, t))
