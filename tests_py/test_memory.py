"""Memory: the estimate counts the tensors the autograd graph really keeps, matches the measured peak
of fresh processes within 25%, and a pass that would not fit raises MemoryLimitError before it runs."""

import os
import platform
import subprocess
import sys

import numpy as np
import pytest

import mipnet
from mipnet.model import memory
from mipnet.autograd import _Node, _topological_order
from mipnet.cli import main
from mipnet.errors import MemoryLimitError, MipnetError

TOLERANCE = 0.25  # estimate / measured peak resident memory


def _pair(n, h, w, seed=0):
    rng = np.random.default_rng(seed)
    left = rng.uniform(0, 255, (n, 3, h, w)).astype(np.float32)
    return left, np.roll(left, -3, axis=3)


def _graph_saved_bytes(model, n, h, w, iters) -> int:
    """Bytes of the distinct arrays the autograd graph of one training forward and loss holds for
    backward, parameters excluded."""
    left, right = _pair(n, h, w)
    gt = np.full((n, 1, h, w), 3.0, np.float32)
    mipnet.manual_seed(0)
    loss = mipnet.model.losses.sequence_loss(model.train()(left, right, iters=iters), gt, gt > 0)

    def buffer(a):
        while isinstance(a.base, np.ndarray):
            a = a.base
        return a

    params = {id(buffer(p.data)) for p in model.parameters()}
    saved = {}
    for node in _topological_order(loss._node):
        if isinstance(node, _Node):
            for a in node.ctx.saved_tensors:
                if isinstance(a, np.ndarray) and id(buffer(a)) not in params:
                    saved[id(buffer(a))] = buffer(a).nbytes
    return sum(saved.values())


@pytest.mark.parametrize("config", [{}, {"use_aff": False}, {"use_ip": False}, {"use_rls": False}, {"rx": 2, "ry": 0}],
                         ids=["full", "no-aff", "no-ip", "no-rls", "rx2-ry0"])
@pytest.mark.parametrize("heads", ["kept", "recomputed"])
def test_the_training_count_is_what_the_graph_saves(config, heads, monkeypatch):
    """activation_terms' training terms (all but the backward's working set and kernel buffers) against the graph, with the
    prediction heads kept (this size) and recomputed (as at large sizes)."""
    if heads == "recomputed":
        monkeypatch.setattr(memory, "HEAD_KEEP_BYTES", 0)
    n, h, w, iters = 2, 64, 80, (2, 3)
    mipnet.manual_seed(0)
    model = mipnet.MIPNet(**config)
    graph = _graph_saved_bytes(model, n, h, w, iters)
    terms = memory.activation_terms(h, w, n, "train", iters, model.config)
    counted = sum(v for k, v in terms.items() if k not in ("backward", "kernel_buffers"))
    assert abs(counted / graph - 1) < 0.03, f"counted {counted / 2**20:.2f} MiB, graph holds {graph / 2**20:.2f} MiB"


@pytest.mark.parametrize("mode, h, w, n", [("eval", 128, 160, 1), ("eval", 384, 512, 1), ("train", 64, 96, 2)])
def test_the_estimate_matches_the_peak_of_a_fresh_process(mode, h, w, n):
    predicted = memory.estimate(h, w, n, mode, (6, 6), mipnet.MIPNet()).total
    measured = memory.measure_peak(h, w, n, mode)
    assert abs(predicted / measured - 1) < TOLERANCE, (
        f"{mode} {h}x{w} batch {n}: estimate {predicted / 2**20:.0f} MiB, measured {measured / 2**20:.0f} MiB")


def test_a_pass_that_does_not_fit_raises_memory_limit_error_first(monkeypatch):
    model = mipnet.MIPNet()
    left, right = _pair(1, 64, 96)
    monkeypatch.setenv("MIPNET_MEMORY_LIMIT", "1M")
    for mode, run in (("eval", lambda: model.eval()(left, right)), ("train", lambda: model.train()(left, right))):
        with pytest.raises(MemoryLimitError) as error:
            run()
        needed = memory.estimate(64, 96, 1, mode, (6, 6), model)
        assert isinstance(error.value, MemoryError) and isinstance(error.value, MipnetError)
        assert error.value.estimate == needed.activations and error.value.available == 0
        assert memory.format_bytes(needed.activations) in str(error.value) and "MIPNET_MEMORY_LIMIT=1M" in str(error.value)
        assert ("training step" if mode == "train" else "eval forward") in str(error.value)
    monkeypatch.setenv("MIPNET_MEMORY_CHECK", "0")
    assert model.eval()(left, right, iters=(1, 1)).shape == (1, 64, 96)


def test_available_memory_is_the_least_of_the_system_and_the_cap(monkeypatch):
    monkeypatch.delenv("MIPNET_MEMORY_LIMIT", raising=False)
    room, source = memory.available_memory()
    assert room > 0 and source
    monkeypatch.setenv("MIPNET_MEMORY_LIMIT", "1G")
    capped, source = memory.available_memory()
    assert capped <= min(room * 1.1, 2**30) and source == "MIPNET_MEMORY_LIMIT=1G"


@pytest.mark.parametrize("text, value", [("123456", 123456), ("512M", 512 * 2**20), ("8G", 8 * 2**30),
                                         ("1.5GiB", 3 * 2**29), ("64k", 64 * 1024), (" 2 T ", 2 * 2**40)])
def test_memory_sizes_parse(text, value):
    assert memory.parse_size(text) == value


def test_a_malformed_memory_cap_is_an_argument_error(monkeypatch):
    monkeypatch.setenv("MIPNET_MEMORY_LIMIT", "lots")
    with pytest.raises(mipnet.errors.ArgumentError, match="'lots'"):
        memory.available_memory()


def test_info_size_prints_the_estimates(capsys):
    assert main(["info", "--size", "100", "200", "--batch", "3", "--iters", "2", "4"]) == 0
    out = capsys.readouterr().out
    model = mipnet.MIPNet()
    for mode in ("eval", "train"):
        assert memory.estimate(100, 200, 3, mode, (2, 4), model).describe() in out


_POLICY_SCRIPT = """
import numpy as np, mipnet
from mipnet.utils import allocator as _allocator
model = mipnet.MIPNet().eval()
with mipnet.no_grad():
    model(np.zeros((1, 3, 32, 64), np.float32), np.zeros((1, 3, 32, 64), np.float32), iters=(1, 1))
print(_allocator.training_policy_active())
x = mipnet.tensor(np.ones(3, np.float32), requires_grad=True)
(x * 2).sum().backward()
print(_allocator.training_policy_active())
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="the policy is glibc's mallopt")
@pytest.mark.parametrize("env, after_backward", [({}, "True"), ({"MIPNET_MALLOC": "default"}, "False")])
def test_the_training_allocator_policy_starts_with_the_first_recorded_op(env, after_backward):
    """Eval leaves glibc's allocator alone; the first op recorded for a backward switches it to the
    training policy (mipnet/_allocator.py), unless MIPNET_MALLOC=default."""
    out = subprocess.run([sys.executable, "-c", _POLICY_SCRIPT], env={**os.environ, **env}, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["False", after_backward]
