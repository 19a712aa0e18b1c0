"""Threads and processes: kernels release the GIL, the pool is resizable, one model serves several
Python threads at once, and the pool survives fork()."""

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


def test_one_model_called_from_two_threads_at_once_gives_the_serial_results():
    """Two Python threads run the same eval model on different pairs concurrently (the kernels release
    the GIL, so the passes overlap); each result is bitwise the serial one."""
    mipnet.manual_seed(0)
    model = mipnet.MIPNet().eval()
    rng = np.random.default_rng(0)
    lefts = [rng.uniform(0, 255, (48, 64, 3)).astype(np.float32) for _ in range(2)]
    pairs = [(left, np.roll(left, -2 - i, axis=1)) for i, left in enumerate(lefts)]
    serial = [model(left, right, iters=(2, 2)) for left, right in pairs]
    results, errors, start = [None, None], [], threading.Barrier(2)

    def worker(i):
        try:
            start.wait()
            for _ in range(2):
                results[i] = model(*pairs[i], iters=(2, 2))
                assert results[i].tobytes() == serial[i].tobytes(), f"thread {i}: differs from the serial result"
        except BaseException as e:  # reported in the main thread
            errors.append(e)

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    assert all(r is not None for r in results)
    assert serial[0].tobytes() != serial[1].tobytes()  # the two threads really computed different pairs


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
