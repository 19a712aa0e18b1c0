"""avg_pool2d and adaptive_avg_pool2d against torch, forward and backward, and their errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from mipnet import _core
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()
F = torch.nn.functional

CASES = [  # (input shape, kwargs)
    ((2, 3, 16, 20), dict(kernel_size=4, stride=4)),
    ((1, 2, 17, 13), dict(kernel_size=4)),
    ((2, 2, 9, 7), dict(kernel_size=3, stride=2, padding=1)),
    ((2, 2, 9, 7), dict(kernel_size=3, stride=2, padding=1, count_include_pad=False)),
    ((1, 3, 10, 11), dict(kernel_size=3, stride=2, padding=1, ceil_mode=True)),
    ((1, 3, 10, 11), dict(kernel_size=3, stride=2, padding=1, ceil_mode=True, count_include_pad=False)),
    ((2, 1, 7, 8), dict(kernel_size=(2, 3), stride=(1, 2), padding=(1, 0), divisor_override=5)),
    ((3, 8, 9), dict(kernel_size=2, ceil_mode=True)),
]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape,kw", CASES)
def test_avg_pool2d_matches_torch(shape, kw, dtype):
    check_op([rand(shape)], lambda x: F.avg_pool2d(x, **kw), lambda x: M.avg_pool2d(x, **kw), dtype=dtype)


@pytest.mark.parametrize("size", [1, (1, 1), (2, 3), (None, 2)])
def test_adaptive_avg_pool2d_divisible_sizes_match_torch(size):
    check_op([rand((2, 3, 6, 12))], lambda x: F.adaptive_avg_pool2d(x, size), lambda x: M.adaptive_avg_pool2d(x, size))


def test_avg_pool2d_accepts_non_contiguous_input():
    x = rand((2, 3, 8, 12), np.float64)
    np.testing.assert_array_equal(_core.avg_pool2d_fwd(non_contiguous(x), (4, 4), (4, 4)), _core.avg_pool2d_fwd(x, (4, 4), (4, 4)))
    g = rand((2, 3, 2, 3), np.float64, seed=1)
    np.testing.assert_array_equal(_core.avg_pool2d_bwd(non_contiguous(g), [2, 3, 8, 12], (4, 4), (4, 4)),
                                  _core.avg_pool2d_bwd(g, [2, 3, 8, 12], (4, 4), (4, 4)))
    out = M.avg_pool2d(mipnet.tensor(non_contiguous(x)), 4).numpy()
    np.testing.assert_allclose(out, F.avg_pool2d(torch.tensor(x), 4).numpy(), rtol=1e-12)


def test_avg_pool2d_errors_name_op_and_shapes():
    x = mipnet.tensor(rand((2, 3, 3, 3)))
    with pytest.raises(mipnet.errors.ShapeError, match=r"avg_pool2d.*larger than the padded input.*\[2, 3, 3, 3\]"):
        M.avg_pool2d(x, 4)
    with pytest.raises(mipnet.errors.ShapeError, match=r"avg_pool2d.*\[3, 3\]"):
        M.avg_pool2d(mipnet.tensor(rand((3, 3))), 2)
    with pytest.raises(mipnet.errors.ShapeError, match=r"avg_pool2d.*empty.*\[2, 0, 4, 4\]"):
        M.avg_pool2d(mipnet.tensor(rand((2, 0, 4, 4))), 2)
    with pytest.raises(mipnet.errors.ArgumentError, match="avg_pool2d: stride"):
        M.avg_pool2d(x, 2, stride=0)
    with pytest.raises(mipnet.errors.ArgumentError, match="avg_pool2d: pad should be at most half"):
        M.avg_pool2d(x, 2, padding=2)
    with pytest.raises(mipnet.errors.ArgumentError, match="avg_pool2d: padding"):
        M.avg_pool2d(x, 2, padding=-1)
    with pytest.raises(mipnet.errors.ArgumentError, match="avg_pool2d: divisor_override"):
        M.avg_pool2d(x, 2, divisor_override=0)
    with pytest.raises(mipnet.errors.DTypeError, match="avg_pool2d"):
        _core.avg_pool2d_fwd(np.zeros((1, 1, 4, 4), np.int32), (2, 2), (2, 2))
    with pytest.raises(mipnet.errors.ShapeError, match=r"avg_pool2d.*\[2, 3, 3, 3\].*\[2, 3, 2, 2\]"):
        _core.avg_pool2d_bwd(rand((2, 3, 2, 2)), [2, 3, 3, 3], (2, 2), (2, 2))
    with pytest.raises(mipnet.errors.ArgumentError, match=r"adaptive_avg_pool2d.*divide"):
        M.adaptive_avg_pool2d(mipnet.tensor(rand((1, 2, 5, 6))), 2)
