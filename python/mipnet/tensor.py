"""``Tensor``: a C-contiguous float32/float64 numpy array plus what autograd needs."""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np

from .errors import DTypeError

__all__ = ["Tensor", "tensor"]

_FLOAT_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


def _as_float_array(data: Any, dtype: Any = None) -> np.ndarray:
    """numpy arrays keep their dtype (which must be float32/float64); Python numbers and lists become
    float32, torch's default dtype. Any other dtype raises ``DTypeError`` instead of being cast."""
    if isinstance(data, Tensor):
        data = data.data
    if dtype is not None:
        dtype = np.dtype(dtype)
        if dtype not in _FLOAT_DTYPES:
            raise DTypeError(f"tensor: dtype must be float32 or float64, got {dtype}")
        return _contiguous(np.asarray(data, dtype=dtype))
    if not isinstance(data, np.ndarray):
        data = np.asarray(data, dtype=np.float32)
    if data.dtype not in _FLOAT_DTYPES:
        raise DTypeError(f"tensor: dtype must be float32 or float64, got {data.dtype} with shape {list(data.shape)}")
    return _contiguous(data)


def _contiguous(a: np.ndarray) -> np.ndarray:
    """C-contiguous, keeping 0-d arrays 0-d (``np.ascontiguousarray`` would make them 1-d)."""
    return a if a.flags.c_contiguous else np.ascontiguousarray(a)


class Tensor:
    """An n-d float array that can record the ops applied to it (``torch.Tensor``'s habits).

    Attributes:
        data: the values, a C-contiguous ``np.ndarray`` (float32 or float64).
        requires_grad: whether ops on it are recorded for ``backward``.
        grad: the accumulated gradient (a ``Tensor``) after ``backward``, or None.
    """

    __array_priority__ = 1000  # ``ndarray * Tensor`` dispatches to ``Tensor.__rmul__``
    __slots__ = ("data", "requires_grad", "grad", "_node", "__weakref__")

    def __init__(self, data: Any, requires_grad: bool = False, dtype: Any = None):
        self.data = _as_float_array(data, dtype)
        self.requires_grad = bool(requires_grad)
        self.grad: Tensor | None = None
        self._node = None

    @classmethod
    def _wrap(cls, array: np.ndarray, requires_grad: bool = False) -> "Tensor":
        t = cls.__new__(cls)
        t.data = _contiguous(np.asarray(array))
        t.requires_grad, t.grad, t._node = requires_grad, None, None
        return t

    # ---- metadata -------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, ...]:
        return self.data.shape

    @property
    def dtype(self) -> np.dtype:
        return self.data.dtype

    @property
    def ndim(self) -> int:
        return self.data.ndim

    @property
    def is_leaf(self) -> bool:
        return self._node is None

    def dim(self) -> int:
        return self.data.ndim

    def size(self, dim: int | None = None):
        return self.data.shape if dim is None else self.data.shape[dim]

    def numel(self) -> int:
        return int(self.data.size)

    def __len__(self) -> int:
        return len(self.data)

    def __repr__(self) -> str:
        grad = ", requires_grad=True" if self.requires_grad else ""
        return f"tensor({np.array2string(self.data, precision=4, threshold=20)}, dtype={self.dtype}{grad})"

    # ---- conversion -----------------------------------------------------------------------------
    def numpy(self) -> np.ndarray:
        """The underlying array (shared, not copied)."""
        return self.data

    def item(self) -> float:
        return float(self.data.item())

    def detach(self) -> "Tensor":
        """The same values, cut from the graph."""
        return Tensor._wrap(self.data)

    def requires_grad_(self, flag: bool = True) -> "Tensor":
        self.requires_grad = flag
        return self

    def double(self) -> "Tensor":
        from . import ops

        return ops.to_dtype(self, np.float64)

    def float(self) -> "Tensor":
        from . import ops

        return ops.to_dtype(self, np.float32)

    def zero_(self) -> "Tensor":
        self.data[...] = 0
        return self

    # ---- autograd -------------------------------------------------------------------------------
    def backward(self, gradient: Any = None) -> None:
        """Accumulates gradients into the ``.grad`` of every leaf this tensor depends on.

        Args:
            gradient: d(loss)/d(self), same shape as self; may be omitted for a one-element tensor.
        """
        from .autograd import backward
        from .errors import ShapeError

        if not self.requires_grad:
            raise RuntimeError("backward: tensor does not require grad and has no grad_fn")
        if gradient is None:
            if self.data.size != 1:
                raise RuntimeError(f"backward: grad can be implicitly created only for scalar outputs, got shape {list(self.shape)}")
            gradient = np.ones_like(self.data)
        g = np.asarray(gradient.data if isinstance(gradient, Tensor) else gradient, dtype=self.dtype)
        if g.shape != self.shape:
            raise ShapeError(f"backward: gradient shape {list(g.shape)} does not match output shape {list(self.shape)}")
        backward(self, _contiguous(g))

    # ---- operators (each one recorded op from mipnet.ops) ----------------------------------------
    def __add__(self, other: Any) -> "Tensor":
        from . import ops

        return ops.add(self, other)

    __radd__ = __add__

    def __sub__(self, other: Any) -> "Tensor":
        from . import ops

        return ops.sub(self, other)

    def __rsub__(self, other: Any) -> "Tensor":
        from . import ops

        return ops.sub(other, self)

    def __mul__(self, other: Any) -> "Tensor":
        from . import ops

        return ops.mul(self, other)

    __rmul__ = __mul__

    def __truediv__(self, other: Any) -> "Tensor":
        from . import ops

        if not np.isscalar(other):
            raise TypeError("Tensor division is only defined by a Python scalar")
        return ops.mul(self, 1.0 / other)

    def __neg__(self) -> "Tensor":
        from . import ops

        return ops.mul(self, -1.0)

    def __getitem__(self, index: Any) -> "Tensor":
        from . import ops

        return ops.index(self, index)

    def reshape(self, *shape: Any) -> "Tensor":
        from . import ops

        return ops.reshape(self, shape[0] if len(shape) == 1 and isinstance(shape[0], (tuple, list)) else shape)

    view = reshape

    def permute(self, *dims: Any) -> "Tensor":
        from . import ops

        return ops.permute(self, dims[0] if len(dims) == 1 and isinstance(dims[0], (tuple, list)) else dims)

    def mean(self, dim: int | Iterable[int] | None = None, keepdim: bool = False) -> "Tensor":
        from . import ops

        return ops.mean(self, dim, keepdim)

    def sum(self, dim: int | Iterable[int] | None = None, keepdim: bool = False) -> "Tensor":
        from . import ops

        return ops.sum(self, dim, keepdim)

    def relu(self) -> "Tensor":
        from . import ops

        return ops.relu(self)

    def sigmoid(self) -> "Tensor":
        from . import ops

        return ops.sigmoid(self)

    def tanh(self) -> "Tensor":
        from . import ops

        return ops.tanh(self)


def tensor(data: Any, requires_grad: bool = False, dtype: Any = None) -> Tensor:
    """A new leaf tensor from an array-like (``torch.tensor``). numpy arrays keep their float dtype."""
    arr = _as_float_array(data, dtype)
    return Tensor._wrap(arr.copy() if arr is data else arr, requires_grad=requires_grad)
