"""Reverse-mode autodiff: ``Function`` (a Rust kernel pair seen from Python) and the tape walk.

Design (docs/architecture.md §4): Rust kernels are stateless ``*_fwd`` / ``*_bwd`` pairs; this
module records which ``Function`` produced each ``Tensor`` and, on ``backward()``, visits the graph
in reverse topological order (iterative DFS: a 12+12-iteration network is thousands of nodes deep).
Gradients of broadcast inputs are summed back to the input's shape here, once, so no op's backward
deals with broadcasting.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

import numpy as np

from .utils import allocator as _allocator
from . import _core
from . import profiler as _profiler
from .errors import DTypeError

__all__ = ["is_grad_enabled", "no_grad", "enable_grad", "Context", "Function", "checkpoint", "backward"]

_state = threading.local()


def is_grad_enabled() -> bool:
    """Whether operations on tensors that require grad are recorded."""
    return getattr(_state, "enabled", True)


class _GradMode:
    def __init__(self, enabled: bool):
        self.enabled = enabled

    def __enter__(self) -> None:
        self.prev = is_grad_enabled()
        _state.enabled = self.enabled

    def __exit__(self, *exc: Any) -> None:
        _state.enabled = self.prev

    def __call__(self, fn: Callable) -> Callable:
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            with self.__class__():
                return fn(*args, **kwargs)

        wrapped.__name__, wrapped.__doc__ = fn.__name__, fn.__doc__
        return wrapped


class no_grad(_GradMode):
    """Context manager / decorator: nothing inside is recorded for backward (``torch.no_grad``)."""

    def __init__(self) -> None:
        super().__init__(False)


class enable_grad(_GradMode):
    """Context manager / decorator re-enabling recording inside a ``no_grad`` block."""

    def __init__(self) -> None:
        super().__init__(True)


class Context:
    """What a ``Function``'s forward leaves for its backward (``torch.autograd.function.FunctionCtx``)."""

    def __init__(self, needs_input_grad: tuple[bool, ...]):
        self.needs_input_grad = needs_input_grad
        self.saved_tensors: tuple = ()
        self.scope = ""

    def save_for_backward(self, *arrays: Any) -> None:
        self.saved_tensors = arrays


class _Node:
    """One recorded op. ``inputs`` has one edge per positional argument: the producing ``_Node`` of a
    non-leaf tensor, the tensor itself for a leaf that requires grad, or None. Edges never hold a
    non-leaf tensor, so an activation that no backward saved is freed as soon as Python drops it
    (as torch's graph does); ``shape`` and ``dtype`` are all the engine needs of the output."""

    __slots__ = ("fn", "ctx", "inputs", "shape", "dtype")

    def __init__(self, fn: type, ctx: Context, inputs: tuple, shape: tuple, dtype: np.dtype):
        self.fn, self.ctx, self.inputs, self.shape, self.dtype = fn, ctx, inputs, shape, dtype


class Function:
    """An op with a forward and a backward on numpy arrays (``torch.autograd.Function``).

    ``forward(ctx, *args, **kwargs)`` receives Tensor arguments as their numpy arrays and returns one
    array; ``backward(ctx, grad)`` returns one gradient (array or None) per positional argument.
    """

    name = "op"
    #: True when ``backward`` returns freshly allocated gradients that nothing else references (as the
    #: Rust kernels do), so the tape may add later contributions into them in place.
    fresh_grads = False

    @staticmethod
    def forward(ctx: Context, *args: Any, **kwargs: Any) -> np.ndarray:
        raise NotImplementedError

    @staticmethod
    def backward(ctx: Context, grad: np.ndarray) -> Any:
        raise NotImplementedError

    @classmethod
    def apply(cls, *args: Any, **kwargs: Any):
        from .tensor import Tensor

        tensors = [a for a in args if isinstance(a, Tensor)]
        dtypes = {t.data.dtype for t in tensors}
        if len(dtypes) > 1:
            shapes = ", ".join(f"{t.data.dtype}{list(t.shape)}" for t in tensors)
            raise DTypeError(f"{cls.name}: inputs must share one dtype, got {shapes}")
        needs = tuple(isinstance(a, Tensor) and a.requires_grad for a in args)
        track = is_grad_enabled() and any(needs)
        if track:  # recording for a backward: training's allocator policy from now on (mipnet/_allocator.py)
            _allocator.use_training_policy()
        ctx = Context(needs)
        arrays = [a.data if isinstance(a, Tensor) else a for a in args]
        prof = _profiler.ACTIVE
        if prof is None:
            out = cls.forward(ctx, *arrays, **kwargs)
        else:
            ctx.scope = prof.scope()
            t0, c0 = time.perf_counter(), time.process_time()
            out = cls.forward(ctx, *arrays, **kwargs)
            prof.add("forward", ctx.scope, cls.name, time.perf_counter() - t0, time.process_time() - c0)
        result = Tensor._wrap(out, requires_grad=track)
        if track:
            edges = tuple((a if a._node is None else a._node) if isinstance(a, Tensor) and a.requires_grad else None
                          for a in args)
            result._node = _Node(cls, ctx, edges, out.shape, out.dtype)
        return result


class _Checkpoint:
    """The tape entry of :func:`checkpoint`: its backward re-runs the function with recording on and
    back-propagates through that fresh graph (the profiler shows the re-run's ops in scope "recompute")."""

    name = "checkpoint"
    fresh_grads = True

    @staticmethod
    def backward(ctx: Context, g: np.ndarray) -> tuple:
        from .tensor import Tensor

        xs = [Tensor._wrap(a, requires_grad=need) for a, need in zip(ctx.saved_tensors, ctx.needs_input_grad)]
        state = [(m, {k: np.array(v, copy=True) for k, v in m._buffers.items()}) for m in ctx.modules]
        with enable_grad(), _profiler.scope("recompute"):
            y = ctx.fn(*xs)
        for m, buffers in state:  # the recomputation must not count twice in running statistics
            m._buffers.update(buffers)
        backward(y, g)
        return tuple(None if x.grad is None else x.grad.data for x in xs)


def checkpoint(fn: Callable, *inputs: Any, modules: Any = ()) -> Any:
    """``fn(*inputs)`` without keeping its intermediate activations (``torch.utils.checkpoint``): the
    forward runs unrecorded, only ``inputs`` are saved, and the backward runs ``fn`` again to
    differentiate it. Worth it where ``fn`` is cheap to recompute and its activations are large.

    ``fn`` takes and returns Tensors; parameters used inside receive gradients as usual. ``modules``:
    the modules ``fn`` runs, whose buffers (BatchNorm running statistics) are restored after the
    recomputation, so they are updated once, by the forward.
    """
    from .tensor import Tensor

    tensors = [a for a in inputs if isinstance(a, Tensor)]
    if not is_grad_enabled() or len(tensors) != len(inputs):
        return fn(*inputs)
    mods = [m for top in modules for m in top.modules()]
    with no_grad():
        out = fn(*(Tensor._wrap(t.data) for t in tensors))
    ctx = Context(tuple(t.requires_grad for t in tensors))
    ctx.saved_tensors = tuple(t.data for t in tensors)
    ctx.fn, ctx.modules = fn, mods
    result = Tensor._wrap(out.data, requires_grad=True)
    edges = tuple((t if t._node is None else t._node) if t.requires_grad else None for t in tensors)
    result._node = _Node(_Checkpoint, ctx, edges, out.data.shape, out.data.dtype)
    return result


def unbroadcast(grad: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Sums a gradient of a broadcast result back to the shape of the input it came from."""
    if grad.shape == tuple(shape):
        return grad
    return _core.sum_to_shape(grad, list(shape))


def _topological_order(root: _Node) -> list:
    """Nodes and leaf tensors reachable from ``root``, each after everything it depends on."""
    order, visited, stack = [], set(), [(root, False)]
    while stack:
        item, expanded = stack.pop()
        if expanded:
            order.append(item)
            continue
        if id(item) in visited:
            continue
        visited.add(id(item))
        stack.append((item, True))
        if isinstance(item, _Node):
            stack.extend((p, False) for p in item.inputs if p is not None and id(p) not in visited)
    return order


def backward(root, grad: np.ndarray) -> None:
    """Accumulates d(root)/d(leaf) · grad into ``.grad`` of every leaf that requires grad, freeing
    each node's saved arrays once it has run (as torch does without ``retain_graph``)."""
    from .tensor import Tensor

    if root._node is None:
        _accumulate(root, grad)
        return
    if root._node.fn is None:
        raise RuntimeError("backward: trying to backward through the graph a second time")
    grads = {id(root._node): grad}
    owned: set[int] = set()  # keys whose gradient array the tape alone references (summed into in place)
    for item in reversed(_topological_order(root._node)):
        g = grads.pop(id(item), None)
        mine = id(item) in owned
        owned.discard(id(item))
        if g is None:
            continue
        if isinstance(item, Tensor):
            _accumulate(item, g, mine)
            continue
        prof = _profiler.ACTIVE
        scope = item.ctx.scope
        if prof is None or item.fn is _Checkpoint:  # a checkpoint's ops are timed one by one
            in_grads = item.fn.backward(item.ctx, g)
        else:
            t0, c0 = time.perf_counter(), time.process_time()
            in_grads = item.fn.backward(item.ctx, g)
            prof.add("backward", scope, item.fn.name, time.perf_counter() - t0, time.process_time() - c0)
        if not isinstance(in_grads, tuple):
            in_grads = (in_grads,)
        # the node's saved arrays and its output gradient go before its input gradients are summed
        fresh = item.fn.fresh_grads
        del g
        item.fn, item.ctx = None, None
        if prof is not None:
            t0, c0 = time.perf_counter(), time.process_time()
        for edge, ig in zip(item.inputs, in_grads):
            if edge is None or ig is None:
                continue
            _add_grad(grads, owned, edge, ig, fresh)
        if prof is not None:
            prof.add("backward", scope, "grad accumulate", time.perf_counter() - t0, time.process_time() - c0)
        item.inputs = ()
        del in_grads


def _add_grad(grads: dict, owned: set, edge, ig: Any, fresh: bool) -> None:
    """grads[edge] += ig, in place when one of the two arrays belongs to the tape alone: a sum the
    tape made, or a fresh gradient of a ``fresh_grads`` op (each array of one backward is distinct)."""
    key = id(edge)
    full = unbroadcast(np.asarray(ig, dtype=edge.dtype), edge.shape)
    mine = (fresh and full is ig) or full is not ig  # a reduced gradient is a new array too
    prev = grads.get(key)
    if prev is None:
        grads[key] = full
        if mine:
            owned.add(key)
    elif key in owned:
        _core.add_(prev, full)
    elif mine:
        _core.add_(full, prev)
        grads[key] = full
        owned.add(key)
    else:
        grads[key] = _core.binary_fwd(prev, full, "add")
        owned.add(key)


def _accumulate(leaf, g: np.ndarray, mine: bool = False) -> None:
    """leaf.grad += g; a first gradient the tape alone references (``mine``) becomes ``.grad`` as it is."""
    from .tensor import Tensor

    if leaf.grad is None:
        leaf.grad = Tensor._wrap(g if mine else g.copy())
    else:
        total = leaf.grad.data
        leaf.grad = Tensor._wrap(_core.binary_fwd(total, np.asarray(g, dtype=total.dtype), "add"))
