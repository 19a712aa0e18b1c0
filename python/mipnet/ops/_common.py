"""Argument coercion shared by the op families."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..tensor import Tensor


def as_tensor(x: Any, like: Tensor | None = None) -> Tensor:
    """A Tensor for a Tensor, numpy array or Python scalar (scalars take the dtype of ``like``)."""
    if isinstance(x, Tensor):
        return x
    if np.isscalar(x) and like is not None:
        return Tensor._wrap(np.asarray(x, dtype=like.dtype))
    return Tensor(x)


def pair(v: Any, name: str, op: str) -> tuple[int, int]:
    """(a, b) from an int or a 2-sequence of ints (``torch.nn.modules.utils._pair``)."""
    from ..errors import ArgumentError

    if isinstance(v, (int, np.integer)):
        return int(v), int(v)
    try:
        a, b = v
        return int(a), int(b)
    except (TypeError, ValueError):
        raise ArgumentError(f"{op}: {name} must be an int or a pair of ints, got {v!r}") from None
