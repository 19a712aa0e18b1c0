"""masked_l1_loss against torch's ``(d - gt).abs()[valid].mean()``: value, gradient, NaN isolation, errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from mipnet import _core
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()


def _torch_loss(d, gt, valid):
    v = valid > 0.5
    # invalid gt zeroed first, or abs's backward turns its NaN into NaN gradients
    return (d - torch.where(v, gt, torch.zeros_like(gt))).abs()[v].mean()


def _mask(shape, seed, frac=0.7):
    return (np.random.default_rng(seed).uniform(size=shape) < frac).astype(np.float32)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(2, 1, 5, 7), (1, 1, 16, 20), (3, 9)])
def test_masked_l1_matches_torch(shape, dtype):
    check_op([rand(shape), rand(shape, seed=1), _mask(shape, 2)], _torch_loss, M.masked_l1_loss,
             grad_inputs=[0], dtype=dtype)


def test_masked_l1_invalid_nan_and_inf_gt_never_reach_value_or_grad():
    shape = (2, 1, 6, 8)
    gt, valid = rand(shape, np.float64, seed=1), _mask(shape, 2).astype(np.float64)
    gt[valid == 0] = np.where(np.arange(int((valid == 0).sum())) % 2, np.nan, np.inf)
    check_op([rand(shape, seed=3), gt, valid], _torch_loss, M.masked_l1_loss, grad_inputs=[0], dtype=np.float64)
    pred = mipnet.tensor(rand(shape, np.float64, seed=3), requires_grad=True)
    M.masked_l1_loss(pred, gt, valid.astype(bool)).backward()
    assert np.all(np.isfinite(pred.grad.numpy()))


def test_masked_l1_without_valid_pixels_is_zero_with_zero_grad():
    pred = mipnet.tensor(rand((2, 3)), requires_grad=True)
    loss = M.masked_l1_loss(pred, np.full((2, 3), np.nan, np.float32), np.zeros((2, 3), bool))
    assert loss.shape == () and loss.item() == 0.0
    loss.backward()
    assert np.all(pred.grad.numpy() == 0)


def test_masked_l1_sign_of_zero_error_is_zero_as_torch():
    d = np.array([1.0, 2.0, 3.0])
    check_op([d, np.array([1.0, 0.0, 5.0]), np.ones(3)], _torch_loss, M.masked_l1_loss, grad_inputs=[0], dtype=np.float64)


def test_masked_l1_accepts_non_contiguous_and_bool_mask():
    shape = (3, 4, 5)
    p, t, v = rand(shape, np.float64), rand(shape, np.float64, seed=1), _mask(shape, 2).astype(np.float64)
    ref = float(_core.masked_l1_fwd(p, t, v))
    assert float(_core.masked_l1_fwd(non_contiguous(p), non_contiguous(t), non_contiguous(v))) == ref
    np.testing.assert_array_equal(_core.masked_l1_bwd(non_contiguous(p), non_contiguous(t), non_contiguous(v), 1.0),
                                  _core.masked_l1_bwd(p, t, v, 1.0))
    assert M.masked_l1_loss(mipnet.tensor(non_contiguous(p)), t, v.astype(bool)).item() == pytest.approx(ref, rel=1e-15)


def test_masked_l1_errors_name_op_and_shapes():
    p = mipnet.tensor(rand((2, 3)))
    with pytest.raises(mipnet.errors.ShapeError, match=r"masked_l1_loss.*input=\[2, 3\], target=\[3, 2\]"):
        M.masked_l1_loss(p, rand((3, 2)), np.ones((2, 3), bool))
    with pytest.raises(mipnet.errors.ShapeError, match=r"masked_l1_loss.*valid=\[2, 2\]"):
        M.masked_l1_loss(p, rand((2, 3)), np.ones((2, 2), bool))
    with pytest.raises(mipnet.errors.ShapeError, match=r"masked_l1_loss.*empty.*\[0, 3\]"):
        M.masked_l1_loss(mipnet.tensor(rand((0, 3))), rand((0, 3)), np.ones((0, 3), bool))
    with pytest.raises(mipnet.errors.DTypeError, match="masked_l1_loss: target"):
        M.masked_l1_loss(p, rand((2, 3), np.float64), np.ones((2, 3), bool))
