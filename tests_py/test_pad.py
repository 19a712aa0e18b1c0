"""pad (constant / replicate) against torch.nn.functional.pad, forward and backward, and its errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()
F = torch.nn.functional

PADS = [[1, 2, 3, 4], [2, 0], [0, 0, 0, 0], [5, 6, 4, 7], [0, 3, 2, 0]]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("mode", ["constant", "replicate"])
@pytest.mark.parametrize("pad", PADS)
def test_pad_matches_torch(mode, pad, dtype):
    # torch's replicate mode refuses a 2-entry pad on a 4-D input; ours pads W only, as [l, r, 0, 0]
    tpad = pad + [0, 0] if len(pad) == 2 else pad
    check_op([rand((2, 3, 4, 5))], lambda x: F.pad(x, tpad, mode=mode), lambda x: M.pad(x, pad, mode=mode), dtype=dtype)


def test_pad_constant_value_and_unbatched_input_match_torch():
    check_op([rand((3, 5, 7))], lambda x: F.pad(x, [1, 2, 0, 3], value=-1.5), lambda x: M.pad(x, [1, 2, 0, 3], value=-1.5))
    check_op([rand((3, 5, 7))], lambda x: F.pad(x, [2, 1, 3, 0], mode="replicate"), lambda x: M.pad(x, [2, 1, 3, 0], mode="replicate"))


def test_pad_ip_seed_shifts_like_the_spec():
    # architecture.md §2.5: replicate pad by r = 1, then one h x w window per diagonal seed
    def seeds(fn_pad, x):
        p = fn_pad(x)
        h, w = x.shape[-2:]
        return [p[:, :, 1 + oy:1 + oy + h, 1 + ox:1 + ox + w] for ox, oy in [(0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1)]]

    x = rand((1, 4, 6, 9), np.float64)
    ours = seeds(lambda a: M.pad(mipnet.tensor(a), [1, 1, 1, 1], mode="replicate"), x)
    theirs = seeds(lambda a: F.pad(torch.tensor(a), [1, 1, 1, 1], mode="replicate"), x)
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a.numpy(), b.numpy())


def test_pad_non_contiguous_input():
    x = non_contiguous(rand((2, 3, 4, 5)))
    out = M.pad(mipnet.tensor(x), [1, 2, 2, 1], mode="replicate").numpy()
    np.testing.assert_array_equal(out, F.pad(torch.tensor(np.ascontiguousarray(x)), [1, 2, 2, 1], mode="replicate").numpy())


def test_pad_errors_name_op_and_shapes():
    x = mipnet.tensor(rand((2, 3, 4, 5)))
    with pytest.raises(mipnet.errors.ArgumentError, match="pad.*reflect"):
        M.pad(x, [1, 1, 1, 1], mode="reflect")
    with pytest.raises(mipnet.errors.ArgumentError, match="pad.*2 or 4 entries"):
        M.pad(x, [1, 1, 1, 1, 1, 1])
    with pytest.raises(mipnet.errors.ArgumentError, match="pad.*negative"):
        M.pad(x, [1, -1, 0, 0])
    with pytest.raises(mipnet.errors.ArgumentError, match="pad.*value"):
        M.pad(x, [1, 1, 1, 1], mode="replicate", value=2.0)
    with pytest.raises(RuntimeError, match=r"pad.*4-D.*\[4, 5\]"):
        M.pad(mipnet.tensor(rand((4, 5))), [1, 1])
    with pytest.raises(RuntimeError, match=r"pad.*empty.*\[2, 0, 4, 5\]"):
        M.pad(mipnet.tensor(np.zeros((2, 0, 4, 5), np.float32)), [1, 1, 1, 1], mode="replicate")
    with pytest.raises(mipnet.errors.DTypeError, match=r"pad.*int32.*\[2, 3, 4, 5\]"):
        mipnet._core.pad2d_fwd(np.zeros((2, 3, 4, 5), np.int32), [1, 1, 1, 1], "constant", 0.0)
    with pytest.raises(RuntimeError, match=r"pad.*\[1, 2, 9, 9\].*\[4, 5\]"):
        mipnet._core.pad2d_bwd(np.zeros((1, 2, 9, 9), np.float32), (4, 5), [1, 1, 1, 1], "replicate")
