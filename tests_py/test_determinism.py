"""Bitwise determinism of the whole model: the same inputs, weights and initial field give identical
disparities, loss and gradients at 1 and 2 threads and on a repeat (every kernel sums in a fixed order)."""

import numpy as np

import mipnet


def _run(threads: int):
    mipnet.set_num_threads(threads)
    try:
        mipnet.manual_seed(0)
        model = mipnet.MIPNet()
        rng = np.random.default_rng(0)
        left = rng.uniform(0, 255, (2, 3, 64, 96)).astype(np.float32)
        right = np.roll(left, -3, axis=3)
        d0 = rng.uniform(0.5, 2.5, (2, 1, 4, 6))
        disp = model.eval()(left, right, iters=(2, 2), disp_init=d0)
        gt = np.full((2, 1, 64, 96), 3.0, np.float32)
        loss = mipnet.losses.sequence_loss(model.train()(left, right, iters=(2, 2), disp_init=d0), gt, gt > 0)
        loss.backward()
        return disp, loss.item(), {k: p.grad.numpy().copy() for k, p in model.named_parameters() if p.grad is not None}
    finally:
        mipnet.set_num_threads(2)


def test_model_is_bitwise_identical_at_1_and_2_threads_and_on_repeat():
    runs = [_run(1), _run(2), _run(2)]
    for disp, loss, grads in runs[1:]:
        assert np.array_equal(disp, runs[0][0])
        assert loss == runs[0][1]
        assert grads.keys() == runs[0][2].keys()
        for k, g in grads.items():
            assert np.array_equal(g, runs[0][2][k]), k
