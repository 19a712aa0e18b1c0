"""The op parity harness (tinygrad's ``helper_test_op`` with a random upstream gradient).

Tolerances live here, in one place, per dtype.
"""

from __future__ import annotations

import importlib
import os
from typing import Callable, Sequence

import numpy as np
import pytest

import mipnet

#: Forward and gradient tolerances (allclose semantics: |a-b| <= atol + rtol*|b|).
TOL = {
    np.float32: dict(atol=1e-5, rtol=1e-4, grad_atol=1e-4, grad_rtol=1e-3),
    np.float64: dict(atol=1e-10, rtol=1e-9, grad_atol=1e-9, grad_rtol=1e-8),
}


def require(module: str):
    """Imports an optional test dependency: outside CI a missing one skips the caller; in CI (env
    ``CI`` set) it is an error, so nothing that CI installs can silently skip."""
    if os.environ.get("CI"):
        return importlib.import_module(module)
    return pytest.importorskip(module)


def require_torch():
    """torch (see :func:`require`)."""
    return require("torch")


def rand(shape: Sequence[int], dtype=np.float32, low: float = -2.0, high: float = 2.0, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(low, high, size=shape).astype(dtype)


def non_contiguous(a: np.ndarray) -> np.ndarray:
    """The same values in a non-contiguous (transposed twice, strided) layout."""
    b = np.asfortranarray(a)
    assert not b.flags.c_contiguous or a.ndim < 2
    return b


def assert_close(ours: np.ndarray, theirs: np.ndarray, atol: float, rtol: float, what: str) -> None:
    assert ours.shape == theirs.shape, f"{what}: shape {ours.shape} vs torch {theirs.shape}"
    assert ours.dtype == theirs.dtype, f"{what}: dtype {ours.dtype} vs torch {theirs.dtype}"
    err = np.abs(ours - theirs)
    bound = atol + rtol * np.abs(theirs)
    worst = np.unravel_index(np.argmax(err - bound), err.shape) if err.size else ()
    assert np.all(err <= bound), f"{what}: max abs err {err.max():.3e} at {worst} (ours {ours[worst]}, torch {theirs[worst]})"


def check_op(
    inputs: Sequence[np.ndarray],
    torch_fn: Callable,
    mipnet_fn: Callable,
    *,
    grad_inputs: Sequence[int] | None = None,
    dtype=np.float32,
    seed: int = 0,
    **tol_override: float,
) -> None:
    """Runs ``torch_fn`` and ``mipnet_fn`` on the same inputs and compares the output and the
    gradients of every input in ``grad_inputs`` (default: all) for a random upstream gradient."""
    torch = require_torch()
    tol = {**TOL[dtype], **tol_override}
    grad_inputs = range(len(inputs)) if grad_inputs is None else grad_inputs
    arrays = [np.asarray(a, dtype=dtype) for a in inputs]
    t_in = [torch.tensor(np.array(a, order="C"), requires_grad=i in grad_inputs) for i, a in enumerate(arrays)]
    m_in = [mipnet.tensor(a, requires_grad=i in grad_inputs) for i, a in enumerate(arrays)]
    t_out, m_out = torch_fn(*t_in), mipnet_fn(*m_in)
    assert_close(m_out.numpy(), t_out.detach().numpy(), tol["atol"], tol["rtol"], "forward")
    if not grad_inputs:
        return
    g = np.random.default_rng(seed + 1).uniform(-1, 1, size=t_out.shape).astype(dtype)
    t_grads = torch.autograd.grad(t_out, [t_in[i] for i in grad_inputs], grad_outputs=torch.tensor(g), allow_unused=True)
    m_out.backward(g)
    for i, tg in zip(grad_inputs, t_grads):
        theirs = np.zeros_like(arrays[i]) if tg is None else tg.numpy()
        assert m_in[i].grad is not None, f"grad of input {i} is None"
        assert_close(m_in[i].grad.numpy(), theirs, tol["grad_atol"], tol["grad_rtol"], f"grad of input {i}")


def sample_right(right, disparity):
    """Right image sampled at (x - d, y), linear along x; and where x - d lies inside the image.

    Shapes
    ------
    right: (H, W, 3), disparity: (H, W) -> (H, W, 3) float64, (H, W) bool.
    """
    height, width = disparity.shape
    y, x = np.indices((height, width))
    xr = x - disparity
    # left neighbour of the sample position, kept so that x0 + 1 is a column
    x0 = np.clip(np.floor(xr).astype(int), 0, width - 2)
    t = np.clip(xr - x0, 0, 1)[..., None]
    r = right.astype(np.float64)
    return (1 - t) * r[y, x0] + t * r[y, x0 + 1], (xr >= 0) & (xr <= width - 1)

