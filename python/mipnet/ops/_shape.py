"""cat, split, narrow, indexing by slices, reshape, permute."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError, ShapeError
from ..tensor import Tensor
from ._common import as_tensor

__all__ = ["cat", "cat_relu", "split", "narrow", "index", "reshape", "permute", "flatten"]


class _Cat(Function):
    name = "cat"
    fresh_grads = True

    @staticmethod
    def forward(ctx, *xs, dim):
        ctx.dim, ctx.sizes = dim, [x.shape[dim] for x in xs]
        return _core.cat_fwd(list(xs), dim)

    @staticmethod
    def backward(ctx, g):
        starts = np.cumsum([0] + ctx.sizes)
        # grad of input i = g[.., starts[i]:starts[i+1], ..] along the cat axis
        return tuple(_core.slice_fwd(g, ctx.dim, int(starts[i]), int(starts[i + 1])) for i in range(len(ctx.sizes)))


class _CatRelu(Function):
    name = "cat_relu"
    fresh_grads = True

    @staticmethod
    def forward(ctx, *xs, dim, relu):
        ctx.dim, ctx.sizes, ctx.relu = dim, [x.shape[dim] for x in xs], relu
        out = _core.cat_fwd(list(xs), dim, list(relu))
        # only the output is kept: relu's backward mask is out > 0 on the relu'd pieces
        ctx.save_for_backward(out)
        return out

    @staticmethod
    def backward(ctx, g):
        (out,) = ctx.saved_tensors
        starts = np.cumsum([0] + ctx.sizes)
        grads = []
        for i, r in enumerate(ctx.relu):
            # grad of input i = g[.., starts[i]:starts[i+1], ..], times [out > 0] where relu'd
            gi = _core.slice_fwd(g, ctx.dim, int(starts[i]), int(starts[i + 1]))
            if r:
                gi = _core.unary_bwd(_core.slice_fwd(out, ctx.dim, int(starts[i]), int(starts[i + 1])), gi, "relu")
            grads.append(gi)
        return tuple(grads)


def _norm_dim(dim: int, ndim: int, op: str, shape: Sequence[int]) -> int:
    if not -ndim <= dim < ndim:
        raise ShapeError(f"{op}: dim {dim} out of range for shape {list(shape)}")
    return dim % ndim


def cat(tensors: Sequence[Tensor], dim: int = 0) -> Tensor:
    """Concatenation along ``dim`` (``torch.cat``)."""
    ts = [as_tensor(t) for t in tensors]
    if not ts:
        raise ArgumentError("cat: expected a non-empty list of tensors")
    return _Cat.apply(*ts, dim=_norm_dim(dim, ts[0].ndim, "cat", ts[0].shape))


def cat_relu(tensors: Sequence[Tensor], relu: Sequence[bool], dim: int = 0) -> Tensor:
    """``cat([relu(t) if r else t for t, r in zip(tensors, relu)], dim)``, keeping only the result for
    the backward (the relu'd inputs are not kept a second time, as separate relu ops would).
    """
    ts = [as_tensor(t) for t in tensors]
    if not ts or len(relu) != len(ts):
        raise ArgumentError(f"cat_relu: expected one relu flag per tensor, got {len(ts)} tensors and {len(relu)} flags")
    return _CatRelu.apply(*ts, dim=_norm_dim(dim, ts[0].ndim, "cat_relu", ts[0].shape), relu=tuple(bool(r) for r in relu))


class _Slice(Function):
    name = "slice"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, axis, start, stop):
        ctx.shape, ctx.axis, ctx.start = list(x.shape), axis, start
        return _core.slice_fwd(x, axis, start, stop)

    @staticmethod
    def backward(ctx, g):
        return _core.slice_bwd(g, ctx.shape, ctx.axis, ctx.start), None, None, None


def narrow(input: Tensor, dim: int, start: int, length: int) -> Tensor:
    """input[.., start:start+length, ..] along ``dim`` (``torch.narrow``)."""
    x = as_tensor(input)
    dim = _norm_dim(dim, x.ndim, "narrow", x.shape)
    return _Slice.apply(x, dim, int(start), int(start) + int(length))


def split(tensor: Tensor, split_size_or_sections: int | Sequence[int], dim: int = 0) -> tuple[Tensor, ...]:
    """Pieces along ``dim`` of a given size, or of the listed sizes (``torch.split``)."""
    x = as_tensor(tensor)
    dim = _norm_dim(dim, x.ndim, "split", x.shape)
    n = x.shape[dim]
    if isinstance(split_size_or_sections, (int, np.integer)):
        step = int(split_size_or_sections)
        sizes = [min(step, n - s) for s in range(0, n, step)]
    else:
        sizes = [int(s) for s in split_size_or_sections]
        if sum(sizes) != n:
            raise ShapeError(f"split: sizes {sizes} do not sum to {n} (shape {list(x.shape)}, dim {dim})")
    starts = np.cumsum([0] + sizes)
    return tuple(narrow(x, dim, int(starts[i]), sizes[i]) for i in range(len(sizes)))


def index(input: Tensor, key: Any) -> Tensor:
    """Basic indexing by ints and step-1 slices (``x[:, :128]``, ``x[0]``); each axis is one recorded slice."""
    x = as_tensor(input)
    key = key if isinstance(key, tuple) else (key,)
    if len(key) > x.ndim:
        raise ShapeError(f"index: too many indices ({len(key)}) for shape {list(x.shape)}")
    out, drop = x, []
    for axis, k in enumerate(key):
        if isinstance(k, (int, np.integer)):
            i = _norm_dim(int(k), x.shape[axis], "index", x.shape)
            out = _Slice.apply(out, axis, i, i + 1)
            drop.append(axis)
        elif isinstance(k, slice):
            start, stop, step = k.indices(x.shape[axis])
            if step != 1:
                raise ArgumentError(f"index: only step-1 slices are supported, got {k}")
            if (start, stop) != (0, x.shape[axis]):
                out = _Slice.apply(out, axis, start, max(start, stop))
        else:
            raise ArgumentError(f"index: unsupported index {k!r} (use ints and slices)")
    if drop:
        out = reshape(out, [s for a, s in enumerate(out.shape) if a not in drop])
    return out


class _Reshape(Function):
    name = "reshape"

    @staticmethod
    def forward(ctx, x, shape):
        ctx.shape = x.shape
        try:
            return x.reshape(shape)
        except ValueError:
            raise ShapeError(f"reshape: cannot reshape {list(x.shape)} into {list(shape)}") from None

    @staticmethod
    def backward(ctx, g):
        return g.reshape(ctx.shape), None


def reshape(input: Tensor, shape: Sequence[int]) -> Tensor:
    """The same values in a new shape (one -1 allowed), as ``torch.reshape`` (metadata only)."""
    return _Reshape.apply(as_tensor(input), tuple(int(s) for s in shape))


def flatten(input: Tensor, start_dim: int = 0, end_dim: int = -1) -> Tensor:
    """Merges axes start_dim..end_dim into one (``torch.flatten``)."""
    x = as_tensor(input)
    s, e = start_dim % max(x.ndim, 1), end_dim % max(x.ndim, 1)
    return reshape(x, list(x.shape[:s]) + [-1] + list(x.shape[e + 1:]))


def _permuted(x: np.ndarray, dims: tuple[int, ...]) -> np.ndarray:
    """x.transpose(dims), contiguous. A rotation of the axes after the first, (0, s, .., n-1, 1, .., s-1)
    (NCHW -> NHWC and back), is one batched transpose (N, A, B) -> (N, B, A) in the core, with
    A = prod(shape[1:s]) and B = prod(shape[s:]); other orders go through numpy."""
    n = x.ndim
    s = dims[1] if n >= 3 else 0
    rotation = s > 1 and dims == (0, *range(s, n), *range(1, s))
    if not rotation or x.dtype not in (np.float32, np.float64):
        return np.ascontiguousarray(x.transpose(dims))
    a, b = int(np.prod(x.shape[1:s])), int(np.prod(x.shape[s:]))
    out = _core.transpose_fwd(x.reshape(x.shape[0], a, b))
    return out.reshape(tuple(x.shape[d] for d in dims))


class _Permute(Function):
    name = "permute"

    @staticmethod
    def forward(ctx, x, dims):
        ctx.inverse = tuple(int(d) for d in np.argsort(dims))
        return _permuted(x, dims)

    @staticmethod
    def backward(ctx, g):
        return _permuted(g, ctx.inverse), None


def permute(input: Tensor, dims: Sequence[int]) -> Tensor:
    """Axes reordered (``torch.permute``); the result is materialised contiguous."""
    x = as_tensor(input)
    dims = tuple(int(d) % x.ndim for d in dims)
    if sorted(dims) != list(range(x.ndim)):
        raise ShapeError(f"permute: dims {list(dims)} are not a permutation of {x.ndim} axes (shape {list(x.shape)})")
    return _Permute.apply(x, dims)
