"""instance_norm and batch_norm against torch: outputs, grads (input, weight, bias), running stats, errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from mipnet import _core
from helpers import assert_close, check_op, non_contiguous, rand, require_torch, TOL

torch = require_torch()
F = torch.nn.functional

DTYPES = [np.float32, np.float64]
SHAPES = [(2, 3, 5, 7), (1, 4, 6, 6), (3, 2, 1, 9)]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES)
def test_instance_norm_matches_torch(shape, dtype):
    check_op([rand(shape)], lambda x: F.instance_norm(x), lambda x: M.instance_norm(x), dtype=dtype)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", SHAPES[:2])
def test_instance_norm_affine_grads_match_torch(shape, dtype):
    c = shape[1]
    check_op([rand(shape), rand((c,), low=0.5, high=1.5, seed=1), rand((c,), seed=2)],
             lambda x, w, b: F.instance_norm(x, weight=w, bias=b, eps=1e-3),
             lambda x, w, b: M.instance_norm(x, weight=w, bias=b, eps=1e-3), dtype=dtype)


def _bn_fns(training, rm_t=None, rv_t=None, rm_m=None, rv_m=None, momentum=0.1):
    def tfn(x, w, b):
        return F.batch_norm(x, rm_t, rv_t, w, b, training=training, momentum=momentum)

    def mfn(x, w, b):
        return M.batch_norm(x, rm_m, rv_m, w, b, training=training, momentum=momentum)

    return tfn, mfn


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("shape", [(2, 3, 5, 7), (4, 6, 1, 1), (1, 2, 3, 3)])
def test_batch_norm_train_outputs_grads_and_running_stats_match_torch(shape, dtype):
    c = shape[1]
    rm0, rv0 = rand((c,), seed=3).astype(dtype), rand((c,), low=0.5, high=2, seed=4).astype(dtype)
    rm_t, rv_t = torch.tensor(rm0), torch.tensor(rv0)
    rm_m, rv_m = rm0.copy(), rv0.copy()
    tfn, mfn = _bn_fns(True, rm_t, rv_t, rm_m, rv_m)
    check_op([rand(shape), rand((c,), low=0.5, high=1.5, seed=1), rand((c,), seed=2)], tfn, mfn, dtype=dtype)
    tol = TOL[dtype]
    assert_close(rm_m, rm_t.numpy(), tol["atol"], tol["rtol"], "running_mean")
    assert_close(rv_m, rv_t.numpy(), tol["atol"], tol["rtol"], "running_var")


@pytest.mark.parametrize("dtype", DTYPES)
def test_batch_norm_eval_affine_only_grads_match_torch(dtype):
    c = 3
    rm, rv = rand((c,), seed=3).astype(dtype), rand((c,), low=0.5, high=2, seed=4).astype(dtype)
    tfn, mfn = _bn_fns(False, torch.tensor(rm), torch.tensor(rv), rm.copy(), rv.copy())
    check_op([rand((2, c, 5, 4)), rand((c,), low=0.5, high=1.5, seed=1), rand((c,), seed=2)], tfn, mfn, dtype=dtype)


def test_batch_norm_without_affine_or_running_stats_matches_torch():
    check_op([rand((3, 4, 3, 5))], lambda x: F.batch_norm(x, None, None, training=True),
             lambda x: M.batch_norm(x, None, None, training=True), dtype=np.float64)


@pytest.mark.parametrize("training", [True, False])
def test_batch_norm_weight_only_matches_torch(training):
    rm, rv = rand((3,), np.float64, seed=3), rand((3,), np.float64, low=0.5, high=2, seed=4)
    check_op([rand((2, 3, 4, 4)), rand((3,), seed=1)],
             lambda x, w: F.batch_norm(x, torch.tensor(rm), torch.tensor(rv), w, training=training),
             lambda x, w: M.batch_norm(x, rm.copy(), rv.copy(), w, training=training), dtype=np.float64)


def test_batch_norm_eval_one_value_per_channel_matches_torch():
    rm, rv = rand((3,), seed=3), rand((3,), low=0.5, high=2, seed=4)
    check_op([rand((1, 3, 1, 1))], lambda x: F.batch_norm(x, torch.tensor(rm), torch.tensor(rv)),
             lambda x: M.batch_norm(x, rm, rv))


@pytest.mark.parametrize("as_tensor", [False, True])
def test_batch_norm_running_stats_after_two_steps_update_in_place(as_tensor):
    c = 4
    rm_t, rv_t = torch.zeros(c, dtype=torch.float64), torch.ones(c, dtype=torch.float64)
    rm_a, rv_a = np.zeros(c), np.ones(c)
    rm_m, rv_m = (mipnet.tensor(rm_a), mipnet.tensor(rv_a)) if as_tensor else (rm_a, rv_a)
    for step in range(2):
        x = rand((3, c, 4, 5), np.float64, seed=10 + step)
        F.batch_norm(torch.tensor(x), rm_t, rv_t, training=True, momentum=0.3)
        M.batch_norm(mipnet.tensor(x), rm_m, rv_m, training=True, momentum=0.3)
    got_m = rm_m.numpy() if as_tensor else rm_m
    got_v = rv_m.numpy() if as_tensor else rv_m
    np.testing.assert_allclose(got_m, rm_t.numpy(), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(got_v, rv_t.numpy(), rtol=1e-12, atol=1e-14)
    # eval after the updates uses them
    x = rand((2, c, 3, 3), np.float64, seed=20)
    ours = M.batch_norm(mipnet.tensor(x), rm_m, rv_m).numpy()
    theirs = F.batch_norm(torch.tensor(x), rm_t, rv_t).numpy()
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)


def test_norm_kernels_accept_non_contiguous_inputs():
    x = rand((2, 3, 5, 7), np.float64)
    xf = non_contiguous(x)
    for y_c, y_f in [(_core.instance_norm_fwd(x)[0], _core.instance_norm_fwd(xf)[0]),
                     (_core.batch_norm_fwd(x, training=True)[0], _core.batch_norm_fwd(xf, training=True)[0])]:
        np.testing.assert_array_equal(y_c, y_f)
    g = rand(x.shape, np.float64, seed=1)
    _, mean, invstd, _, _ = _core.batch_norm_fwd(x, training=True)
    np.testing.assert_array_equal(_core.batch_norm_bwd(x, mean, invstd, g, training=True)[0],
                                  _core.batch_norm_bwd(xf, mean, invstd, non_contiguous(g), training=True)[0])
    out = M.instance_norm(mipnet.tensor(xf)).numpy()
    np.testing.assert_allclose(out, F.instance_norm(torch.tensor(x)).numpy(), rtol=1e-10, atol=1e-12)


def test_norm_errors_name_op_and_shapes():
    x = mipnet.tensor(rand((2, 3, 4, 4)))
    with pytest.raises(RuntimeError, match=r"batch_norm: Expected more than 1 value per channel when training.*\[1, 3, 1, 1\]"):
        M.batch_norm(mipnet.tensor(rand((1, 3, 1, 1))), None, None, training=True)
    with pytest.raises(RuntimeError, match=r"instance_norm: Expected more than 1 spatial element.*\[2, 3, 1, 1\]"):
        M.instance_norm(mipnet.tensor(rand((2, 3, 1, 1))))
    with pytest.raises(mipnet.errors.ShapeError, match=r"instance_norm.*4-D.*\[2, 3, 4\]"):
        M.instance_norm(mipnet.tensor(rand((2, 3, 4))))
    with pytest.raises(mipnet.errors.ShapeError, match=r"batch_norm.*input=\[2, 3, 4, 4\], weight=\[4\]"):
        M.batch_norm(x, None, None, rand((4,)), training=True)
    with pytest.raises(mipnet.errors.ShapeError, match=r"batch_norm.*running_mean=\[2\]"):
        M.batch_norm(x, rand((2,)), rand((2,)))
    with pytest.raises(mipnet.errors.ShapeError, match=r"instance_norm.*empty.*\[0, 3, 4, 4\]"):
        M.instance_norm(mipnet.tensor(rand((0, 3, 4, 4))))
    with pytest.raises(mipnet.errors.ArgumentError, match="batch_norm.*evaluation mode"):
        M.batch_norm(x, None, None, training=False)
    with pytest.raises(mipnet.errors.ArgumentError, match="instance_norm.*not supported"):
        M.instance_norm(x, running_mean=np.zeros(3, np.float32), running_var=np.ones(3, np.float32))
    with pytest.raises(mipnet.errors.ArgumentError, match="instance_norm.*not supported"):
        M.instance_norm(x, use_input_stats=False)
    with pytest.raises(mipnet.errors.DTypeError, match="batch_norm"):
        M.batch_norm(x, None, None, mipnet.tensor(rand((3,), np.float64)), training=True)
    with pytest.raises(mipnet.errors.DTypeError, match="batch_norm: running_mean"):
        M.batch_norm(x, np.zeros(3), np.ones(3), training=True)
    with pytest.raises(mipnet.errors.DTypeError, match="instance_norm"):
        _core.instance_norm_fwd(np.zeros((2, 3, 4, 4), np.int64))
    with pytest.raises(mipnet.errors.ShapeError, match=r"instance_norm.*\[2, 3, 4, 4\].*\[2, 3, 4, 5\]"):
        y, m, s = _core.instance_norm_fwd(x.numpy())
        _core.instance_norm_bwd(x.numpy(), m, s, rand((2, 3, 4, 5)))


@pytest.mark.parametrize("bias", [True, False])
def test_eval_batch_norm_folded_into_conv_matches_both_layers_with_grads(bias):
    """Eval-mode MS-CAM branches fold each BatchNorm into its convolution (BatchNorm2d.folded): output and
    gradients (input, conv weight and bias, BN weight and bias) equal the two layers applied in turn."""
    from mipnet.model.blocks import MSCAMBranch
    from mipnet.nn import BatchNorm2d, Conv2d

    rng = np.random.default_rng(3)
    conv, bn = Conv2d(6, 5, 3, padding=1, bias=bias).double(), BatchNorm2d(5).double()
    bn.running_mean[:], bn.running_var[:] = rng.normal(size=5), rng.uniform(0.3, 3.0, 5)
    bn.weight.data[:], bn.bias.data[:] = rng.normal(size=5), rng.normal(size=5)
    bn.eval()
    x = rand((2, 6, 7, 9), np.float64)
    params = [p for p in (conv.weight, conv.bias, bn.weight, bn.bias) if p is not None]

    def outputs_and_grads(fn):
        xt = mipnet.tensor(x, requires_grad=True)
        for p in params:
            p.grad = None
        y = fn(xt)
        (y * mipnet.tensor(rand(y.shape, np.float64, seed=4))).sum().backward()
        return [y.numpy(), xt.grad.numpy()] + [p.grad.numpy() for p in params]

    def folded(xt):
        w, b = bn.folded(conv)
        return M.conv2d(xt, w, b, 1, 1)

    for ours, ref in zip(outputs_and_grads(folded), outputs_and_grads(lambda xt: bn(conv(xt)))):
        np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-12)

    branch = MSCAMBranch(8).double()
    for norm in (branch.bn1, branch.bn2):
        norm.running_mean[:], norm.running_var[:] = rng.normal(size=norm.num_features), rng.uniform(0.3, 3.0, norm.num_features)
    branch.eval()
    z = mipnet.tensor(rand((2, 8, 5, 6), np.float64))
    two_layers = branch.bn2(branch.conv2(M.relu(branch.bn1(branch.conv1(z)))))
    np.testing.assert_allclose(branch(z).numpy(), two_layers.numpy(), rtol=1e-12, atol=1e-12)

    with pytest.raises(mipnet.errors.ShapeError, match=r"BatchNorm2d.folded.*6 output channels.*5"):
        bn.folded(Conv2d(5, 6, 1).double())
    bn.train()
    with pytest.raises(mipnet.errors.ArgumentError, match="BatchNorm2d.folded.*eval-mode"):
        bn.folded(conv)
