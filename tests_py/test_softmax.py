"""softmax against torch along every dim (negative too), forward and backward, and its errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from mipnet import _core
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()
F = torch.nn.functional


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("dim", [0, 1, 2, 3, -1, -3])
def test_softmax_matches_torch(dim, dtype):
    check_op([rand((2, 3, 5, 7), low=-4, high=4)], lambda x: torch.softmax(x, dim), lambda x: M.softmax(x, dim), dtype=dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_softmax_convex_mask_layout_matches_torch(dtype):
    # torch.softmax(M.view(N, 1, 9, 4, 4, h, w), dim=2) of convex upsampling
    check_op([rand((2, 1, 9, 4, 4, 3, 5))], lambda x: torch.softmax(x, dim=2), lambda x: M.softmax(x, dim=2), dtype=dtype)


def test_softmax_rank1_large_logits_and_dtype_argument_match_torch():
    check_op([np.array([1000.0, 999.0, -1000.0, 0.5])], lambda x: F.softmax(x, 0), lambda x: M.softmax(x, 0))
    check_op([rand((3, 4))], lambda x: F.softmax(x, -1, dtype=torch.float64),
             lambda x: M.softmax(x, -1, dtype=np.float64), grad_atol=1e-6, grad_rtol=1e-6)


def test_softmax_accepts_non_contiguous_input():
    x = rand((3, 4, 5), np.float64)
    for dim in (0, 2):
        np.testing.assert_array_equal(_core.softmax_fwd(non_contiguous(x), dim), _core.softmax_fwd(x, dim))
        y, g = _core.softmax_fwd(x, dim), rand(x.shape, np.float64, seed=1)
        np.testing.assert_array_equal(_core.softmax_bwd(non_contiguous(y), non_contiguous(g), dim), _core.softmax_bwd(y, g, dim))
    np.testing.assert_allclose(M.softmax(mipnet.tensor(non_contiguous(x)), 1).numpy(), torch.softmax(torch.tensor(x), 1).numpy(), rtol=1e-12)


def test_softmax_errors_name_op_and_shapes():
    x = mipnet.tensor(rand((2, 3)))
    with pytest.raises(mipnet.errors.ShapeError, match=r"softmax: Dimension out of range.*\[-2, 1\].*\[2, 3\]"):
        M.softmax(x, 2)
    with pytest.raises(mipnet.errors.ShapeError, match=r"softmax.*empty.*\[0, 3\]"):
        M.softmax(mipnet.tensor(rand((0, 3))), 1)
    with pytest.raises(mipnet.errors.ArgumentError, match="softmax: dim"):
        M.softmax(x)
    with pytest.raises(mipnet.errors.DTypeError, match="softmax"):
        _core.softmax_fwd(np.zeros((2, 3), np.int64), 1)
    with pytest.raises(mipnet.errors.ShapeError, match=r"softmax.*\[2, 3\].*\[3, 2\]"):
        _core.softmax_bwd(rand((2, 3)), rand((3, 2)), 1)
