"""mipnet.profiler: per-op-family table (forward, backward, counts, share), scopes, MIPNET_PROFILE=1."""

import os
import subprocess
import sys

import numpy as np

import mipnet
import mipnet.ops as M
from mipnet import profiler


def test_table_counts_forward_and_backward_per_op_family():
    x = mipnet.tensor(np.random.default_rng(0).standard_normal((1, 3, 8, 8)).astype(np.float32), requires_grad=True)
    w = mipnet.tensor(np.random.default_rng(1).standard_normal((4, 3, 3, 3)).astype(np.float32), requires_grad=True)
    with profiler.profile() as p:
        with profiler.scope("block"):
            y = M.relu(M.conv2d(x, w, padding=1))
            y = M.relu(y)
        y.sum().backward()
        with profiler.record("optimizer"):
            pass
    rows = p.totals()
    assert rows["relu"]["forward"].count == 2 and rows["relu"]["backward"].count == 2
    assert rows["conv2d"]["forward"].count == 1 and rows["conv2d"]["backward"].count == 1
    assert rows["optimizer"]["other"].count == 1
    assert "block/conv2d" in p.totals(by_scope=True)
    table = p.table()
    for word in ("conv2d", "relu", "share", "CPU/wall", "total (wall)", "optimizer"):
        assert word in table
    assert "block forward" in p.scope_table()
    assert profiler.ACTIVE is None


def test_environment_variable_prints_the_table_at_exit():
    code = "import numpy as np, mipnet, mipnet.ops as M; M.relu(mipnet.tensor(np.ones((2, 2), np.float32)))"
    env = {**os.environ, "MIPNET_PROFILE": "1"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert "mipnet profile (MIPNET_PROFILE=1)" in out.stderr and "relu" in out.stderr
