"""Activations, broadcasting arithmetic, means and shape ops against torch, forward and backward."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from helpers import check_op, rand, require_torch

torch = require_torch()
F = torch.nn.functional


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("name", ["relu", "sigmoid", "tanh"])
def test_activation_matches_torch(name, dtype):
    check_op([rand((2, 3, 5, 7))], getattr(torch, name), getattr(M, name), dtype=dtype)


@pytest.mark.parametrize("op", ["add", "sub", "mul"])
@pytest.mark.parametrize("sa,sb", [((2, 3, 5, 7), (2, 3, 5, 7)), ((2, 3, 5, 7), (2, 3, 1, 1)),
                                   ((2, 3, 5, 7), (1, 3, 1, 1)), ((1, 3, 1, 1), (2, 3, 4, 5)), ((3, 1, 7), (2, 1, 4, 1))])
def test_broadcasting_binary_sums_grads_to_each_shape(op, sa, sb):
    check_op([rand(sa, seed=1), rand(sb, seed=2)], getattr(torch, op), getattr(M, op))


def test_scalar_arithmetic_gate_expression_matches_torch():
    # iAFF gating: w*x + (1 - w)*y with a broadcast w
    def fn(w, x, y):
        return w * x + (1 - w) * y - 0.5 * x / 2.0
    check_op([rand((2, 4, 1, 1)), rand((2, 4, 3, 5), seed=3), rand((2, 4, 3, 5), seed=4)], fn, fn)


@pytest.mark.parametrize("dim,keepdim", [((2, 3), True), (1, True), (1, False), (None, False)])
def test_mean_matches_torch(dim, keepdim):
    tdim = (0, 1, 2, 3) if dim is None else dim
    check_op([rand((2, 6, 5, 7))], lambda x: x.mean(dim=tdim, keepdim=keepdim), lambda x: x.mean(dim, keepdim))


def test_cat_split_index_reshape_permute_match_torch():
    def tfn(a, b):
        c = torch.cat([a, b, a], 1)
        p, q = torch.split(c, [3, 5], 1)
        return (p[:, 1:, 2:5].reshape(2, -1) * q[1, :, 0].reshape(1, -1)[:, :2 * 3 * 7 // 7 * 1].sum() + 1).permute(1, 0)

    def mfn(a, b):
        c = M.cat([a, b, a], 1)
        p, q = M.split(c, [3, 5], 1)
        return (p[:, 1:, 2:5].reshape(2, -1) * q[1, :, 0].reshape(1, -1)[:, :6].sum() + 1).permute(1, 0)

    check_op([rand((2, 3, 5, 7)), rand((2, 2, 5, 7), seed=5)], tfn, mfn)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape,dims", [((2, 35, 5, 7), (0, 2, 3, 1)), ((2, 5, 7, 35), (0, 3, 1, 2)),
                                        ((3, 17, 40), (0, 2, 1)), ((2, 3, 4, 5), (0, 2, 1, 3)), ((2, 3, 4), (2, 0, 1))])
def test_permute_matches_torch_forward_and_backward(shape, dims, dtype):
    # axis rotations after the batch axis (NCHW <-> NHWC) take the core's batched transpose (35 x 35
    # and 17 x 40: bands and blocks with remainders); other orders take numpy
    check_op([rand(shape)], lambda x: x.permute(*dims), lambda x: x.permute(*dims), dtype=dtype)


@pytest.mark.parametrize("relu", [[True, False, True], [False, False, False], [True, True, True]])
def test_cat_relu_matches_torch(relu):
    def tfn(*xs):
        return torch.cat([F.relu(x) if r else x for x, r in zip(xs, relu)], 1)

    check_op([rand((2, 3, 5, 7)), rand((2, 2, 5, 7), seed=5), rand((2, 4, 5, 7), seed=6)], tfn,
             lambda *xs: M.cat_relu(list(xs), relu, 1))


def test_non_contiguous_numpy_inputs_are_accepted():
    a = np.asfortranarray(rand((3, 4, 5)))
    out = M.tanh(mipnet.tensor(a)).numpy()
    np.testing.assert_allclose(out, np.tanh(a), rtol=1e-6)


def test_autograd_graph_with_reuse_and_broadcast_matches_torch():
    # x is used three times and b is broadcast twice: grads must accumulate as torch's do.
    def fn(x, b):
        h = (x * b).tanh()
        return (h * x + b).sigmoid() * h - x.mean((2, 3), keepdim=True)

    check_op([rand((2, 3, 4, 5)), rand((1, 3, 1, 1), seed=7)], fn, fn, dtype=np.float64)


def test_long_chain_backward_is_iterative():
    x = mipnet.tensor(np.ones(3, np.float64), requires_grad=True)
    y = x
    for _ in range(5000):
        y = y * 1.0001
    y.sum().backward()
    np.testing.assert_allclose(x.grad.numpy(), np.full(3, 1.0001 ** 5000), rtol=1e-9)


def test_no_grad_records_nothing():
    x = mipnet.tensor(np.ones(3, np.float32), requires_grad=True)
    with mipnet.no_grad():
        y = x * 2
    assert not y.requires_grad


def test_errors_name_op_and_shapes():
    a, b = mipnet.tensor(rand((2, 3))), mipnet.tensor(rand((4, 5)))
    with pytest.raises(RuntimeError, match=r"add.*\[2, 3\].*\[4, 5\]"):
        M.add(a, b)
    with pytest.raises(mipnet.errors.DTypeError, match="float32 or float64"):
        mipnet.tensor(np.zeros(3, np.int32))
    with pytest.raises(mipnet.errors.DTypeError, match="mul"):
        M.mul(a, mipnet.tensor(rand((2, 3), np.float64)))
    with pytest.raises(mipnet.errors.ShapeError, match="cat"):
        M.cat([a, b], 1)
    with pytest.raises(mipnet.errors.ShapeError, match="backward"):
        (mipnet.tensor(rand((2, 3)), requires_grad=True) * 2).backward(np.ones((3, 3), np.float32))
