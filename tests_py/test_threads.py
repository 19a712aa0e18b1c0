"""Threads and processes: kernels release the GIL, the pool is resizable, and survives fork()."""

import ast
import multiprocessing as mp
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import mipnet
from mipnet import _core


def _heavy_conv():
    x = np.random.default_rng(0).normal(size=(1, 64, 96, 128)).astype(np.float32)
    w = np.random.default_rng(1).normal(size=(64, 64, 3, 3)).astype(np.float32)
    return lambda: _core.conv2d_fwd(x, w, None, (1, 1), (1, 1))


def test_heavy_kernel_releases_the_gil():
    """While a conv kernel runs in another thread, this thread keeps executing Python bytecode:
    some of its timestamps fall strictly inside the kernel's [start, end] window."""
    run = _heavy_conv()
    window = {}

    def worker():
        window["start"] = time.perf_counter()
        for _ in range(3):
            run()
        window["end"] = time.perf_counter()

    t = threading.Thread(target=worker)
    stamps = []
    t.start()
    while t.is_alive():
        stamps.append(time.perf_counter())
    t.join()
    inside = [s for s in stamps if window["start"] < s < window["end"]]
    assert len(inside) > 100, f"only {len(inside)} Python steps ran while the kernel held the CPU"


def test_set_num_threads_resizes_the_pool():
    before = mipnet.get_num_threads()
    try:
        mipnet.set_num_threads(1)
        assert mipnet.get_num_threads() == 1
        assert _heavy_conv()().shape == (1, 64, 96, 128)
    finally:
        mipnet.set_num_threads(before)
    with pytest.raises(RuntimeError, match="at least 1"):
        mipnet.set_num_threads(0)


def _child(queue):
    queue.put(float(_heavy_conv()().sum()))


def test_kernels_work_in_a_forked_child_after_the_parent_used_the_pool():
    expected = float(_heavy_conv()().sum())  # the parent's pool threads exist now
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    p = ctx.Process(target=_child, args=(queue,))
    p.start()
    p.join(timeout=120)
    assert p.exitcode == 0, "the forked child hung or crashed using the thread pool"
    assert queue.get(timeout=5) == pytest.approx(expected, rel=1e-6)


def test_stub_lists_exactly_the_compiled_functions():
    stub = ast.parse((Path(mipnet.__file__).parent / "_core.pyi").read_text())
    declared = {n.name for n in stub.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    compiled = {n for n in dir(_core) if not n.startswith("__")}
    assert declared == compiled, f"missing from stub: {compiled - declared}; stale in stub: {declared - compiled}"
