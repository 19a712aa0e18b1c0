"""Bitwise reproducibility: the same inputs, weights and seeds give identical eval disparities and an
identical training step (loss and every parameter gradient) at 1 and at 2 kernel threads and on a
repeat (64x96, batch 2, iters (6, 6)). The speed work must keep this: README, "Reproducibility"."""

import numpy as np
import pytest

import mipnet

N, H, W = 2, 64, 96


@pytest.fixture(scope="module")
def weights():
    mipnet.manual_seed(0)
    return mipnet.MIPNet().state_dict()


@pytest.fixture(scope="module")
def batch():
    rng = np.random.default_rng(0)
    left = rng.uniform(0, 255, (N, 3, H, W)).astype(np.float32)
    right = np.roll(left, -5, axis=3)
    disparity = rng.uniform(1, 20, (N, 1, H, W)).astype(np.float32)
    return left, right, disparity


def _model(weights):
    model = mipnet.MIPNet()
    model.load_state_dict(weights)
    return model


def _with_threads(n, fn):
    before = mipnet.get_num_threads()
    mipnet.set_num_threads(n)
    try:
        return fn()
    finally:
        mipnet.set_num_threads(before)


def _eval(weights, batch):
    left, right, _ = batch
    return _model(weights).eval()(left, right, seed=3)


def _train_step(weights, batch):
    """(loss, {name: gradient}) of one training step; the gamma initialisation is seeded."""
    left, right, disparity = batch
    model = _model(weights).train()
    mipnet.manual_seed(11)
    loss = mipnet.model.losses.sequence_loss(model(left, right), disparity, disparity > 0)
    loss.backward()
    return loss.numpy().copy(), {name: p.grad.numpy().copy() for name, p in model.named_parameters()}


def _identical(a, b, what):
    assert a.dtype == b.dtype and a.shape == b.shape, what
    assert a.tobytes() == b.tobytes(), f"{what}: differs bitwise (max |diff| {np.max(np.abs(a - b)):.3e})"


def test_eval_disparities_are_bitwise_identical_at_1_and_2_threads_and_on_a_repeat(weights, batch):
    one = _with_threads(1, lambda: _eval(weights, batch))
    two = _with_threads(2, lambda: _eval(weights, batch))
    again = _with_threads(2, lambda: _eval(weights, batch))
    assert one.shape == (N, H, W) and np.all(np.isfinite(one))
    _identical(one, two, "eval disparity, 1 vs 2 threads")
    _identical(two, again, "eval disparity, repeat")


def test_a_training_step_is_bitwise_identical_at_1_and_2_threads_and_on_a_repeat(weights, batch):
    loss1, grads1 = _with_threads(1, lambda: _train_step(weights, batch))
    loss2, grads2 = _with_threads(2, lambda: _train_step(weights, batch))
    loss3, grads3 = _with_threads(2, lambda: _train_step(weights, batch))
    assert np.isfinite(loss1) and len(grads1) == 284
    _identical(loss1, loss2, "loss, 1 vs 2 threads")
    _identical(loss2, loss3, "loss, repeat")
    for name in grads1:
        _identical(grads1[name], grads2[name], f"grad of {name}, 1 vs 2 threads")
        _identical(grads2[name], grads3[name], f"grad of {name}, repeat")
