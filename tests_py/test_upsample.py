"""Convex upsampling against RAFT's exact PyTorch code (architecture.md §2.8), forward and backward, and errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()
F = torch.nn.functional


def raft_upsample(flow, mask, rate=4):
    n, d, h, w = flow.shape
    mask = torch.softmax(mask.view(n, 1, 9, rate, rate, h, w), dim=2)
    up = F.unfold(rate * flow, [3, 3], padding=1).view(n, d, 9, 1, 1, h, w)
    up = torch.sum(mask * up, dim=2)
    return up.permute(0, 1, 4, 2, 5, 3).reshape(n, d, rate * h, rate * w)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n,d,h,w,r", [(2, 2, 5, 7, 4), (1, 2, 3, 4, 4), (1, 1, 2, 3, 2), (1, 3, 1, 1, 3), (1, 2, 6, 5, 1)])
def test_convex_upsample_matches_raft(n, d, h, w, r, dtype):
    check_op([rand((n, d, h, w), low=-4, high=4), rand((n, 9 * r * r, h, w), seed=1, low=-3, high=3)],
             lambda f, m: raft_upsample(f, m, r), lambda f, m: M.convex_upsample(f, m, rate=r), dtype=dtype)


def test_convex_upsample_non_contiguous_and_default_rate():
    f, m = rand((1, 2, 4, 5)), rand((1, 144, 4, 5), seed=2)
    ours = M.convex_upsample(mipnet.tensor(non_contiguous(f)), mipnet.tensor(non_contiguous(m))).numpy()
    np.testing.assert_allclose(ours, raft_upsample(torch.tensor(f), torch.tensor(m)).numpy(), rtol=1e-5, atol=1e-5)


def test_convex_upsample_errors_name_op_and_shapes():
    f = mipnet.tensor(rand((1, 2, 3, 4)))
    with pytest.raises(RuntimeError, match=r"convex_upsample.*144.*\[1, 2, 3, 4\].*\[1, 143, 3, 4\]"):
        M.convex_upsample(f, mipnet.tensor(rand((1, 143, 3, 4))))
    with pytest.raises(RuntimeError, match=r"convex_upsample.*\[1, 2, 3, 4\].*\[1, 144, 3, 5\]"):
        M.convex_upsample(f, mipnet.tensor(rand((1, 144, 3, 5))))
    with pytest.raises(mipnet.errors.ArgumentError, match="convex_upsample.*rate"):
        M.convex_upsample(f, mipnet.tensor(rand((1, 144, 3, 4))), rate=0)
    with pytest.raises(RuntimeError, match=r"convex_upsample.*4-D.*\[2, 3, 4\]"):
        M.convex_upsample(mipnet.tensor(rand((2, 3, 4))), mipnet.tensor(rand((1, 144, 3, 4))))
    with pytest.raises(RuntimeError, match=r"convex_upsample.*empty.*\[1, 2, 0, 4\]"):
        M.convex_upsample(mipnet.tensor(np.zeros((1, 2, 0, 4), np.float32)), mipnet.tensor(np.zeros((1, 144, 0, 4), np.float32)))
    with pytest.raises(mipnet.errors.DTypeError, match=r"convex_upsample.*float32.*float64\[1, 144, 3, 4\]"):
        M.convex_upsample(f, mipnet.tensor(rand((1, 144, 3, 4), np.float64)))
