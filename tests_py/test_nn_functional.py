"""mipnet.nn.functional against torch.nn.functional: forward and input gradients on random float32 inputs."""

from __future__ import annotations

import numpy as np
import pytest

import mipnet
import mipnet.nn.functional as F
from helpers import check_op, rand, require_torch
from mipnet.errors import ArgumentError

torch = require_torch()
TF = torch.nn.functional

X = rand((2, 3, 8, 10), seed=1)
Y = rand((2, 3, 8, 10), seed=2)
W = rand((4, 3, 3, 3), seed=3, low=-0.5, high=0.5)
B = rand((4,), seed=4)
GRID = rand((2, 5, 6, 2), seed=5, low=-1.1, high=1.1)
AFFINE = rand((3,), seed=6, low=0.5, high=1.5)

CASES = {
    "conv2d": ([X, W, B], lambda x, w, b: TF.conv2d(x, w, b, stride=2, padding=1),
               lambda x, w, b: F.conv2d(x, w, b, stride=2, padding=1)),
    "relu": ([X], TF.relu, F.relu),
    "sigmoid": ([X], TF.sigmoid, F.sigmoid),
    "tanh": ([X], TF.tanh, F.tanh),
    "softmax": ([X], lambda x: TF.softmax(x, dim=1), lambda x: F.softmax(x, dim=1)),
    "leaky_relu": ([X], lambda x: TF.leaky_relu(x, negative_slope=0.2), lambda x: F.leaky_relu(x, negative_slope=0.2)),
    "leaky_relu default": ([X], TF.leaky_relu, F.leaky_relu),
    "hardtanh": ([X], lambda x: TF.hardtanh(x, -0.5, 1.5), lambda x: F.hardtanh(x, -0.5, 1.5)),
    "relu6": ([X * 4], TF.relu6, F.relu6),
    "silu": ([X], TF.silu, F.silu),
    "avg_pool2d": ([X], lambda x: TF.avg_pool2d(x, 3, stride=2, padding=1, count_include_pad=False),
                   lambda x: F.avg_pool2d(x, 3, stride=2, padding=1, count_include_pad=False)),
    "adaptive_avg_pool2d": ([X], lambda x: TF.adaptive_avg_pool2d(x, (4, 5)), lambda x: F.adaptive_avg_pool2d(x, (4, 5))),
    "pad replicate": ([X], lambda x: TF.pad(x, [1, 2, 3, 0], mode="replicate"),
                      lambda x: F.pad(x, [1, 2, 3, 0], mode="replicate")),
    "interpolate": ([X], lambda x: TF.interpolate(x, size=(13, 7), mode="bilinear", align_corners=False),
                    lambda x: F.interpolate(x, size=(13, 7), mode="bilinear", align_corners=False)),
    "grid_sample": ([X, GRID], lambda x, g: TF.grid_sample(x, g, mode="bilinear", padding_mode="zeros", align_corners=True),
                    lambda x, g: F.grid_sample(x, g, mode="bilinear", padding_mode="zeros", align_corners=True)),
    "unfold": ([X], lambda x: TF.unfold(x, 3, padding=1, stride=2), lambda x: F.unfold(x, 3, padding=1, stride=2)),
    "instance_norm": ([X, AFFINE, B[:3]], lambda x, w, b: TF.instance_norm(x, weight=w, bias=b),
                      lambda x, w, b: F.instance_norm(x, weight=w, bias=b)),
    "batch_norm training": ([X, AFFINE, B[:3]], lambda x, w, b: TF.batch_norm(x, None, None, w, b, training=True),
                            lambda x, w, b: F.batch_norm(x, None, None, w, b, training=True)),
    "l1_loss": ([X, Y], TF.l1_loss, F.l1_loss),
    "l1_loss sum": ([X, Y], lambda x, y: TF.l1_loss(x, y, reduction="sum"), lambda x, y: F.l1_loss(x, y, reduction="sum")),
    "mse_loss": ([X, Y], TF.mse_loss, F.mse_loss),
    "mse_loss none": ([X, Y], lambda x, y: TF.mse_loss(x, y, reduction="none"),
                      lambda x, y: F.mse_loss(x, y, reduction="none")),
    "smooth_l1_loss": ([X, Y], lambda x, y: TF.smooth_l1_loss(x, y, beta=0.7),
                       lambda x, y: F.smooth_l1_loss(x, y, beta=0.7)),
    "smooth_l1_loss beta 0": ([X, Y], lambda x, y: TF.smooth_l1_loss(x, y, reduction="sum", beta=0.0),
                              lambda x, y: F.smooth_l1_loss(x, y, reduction="sum", beta=0.0)),
    "huber_loss": ([X, Y], lambda x, y: TF.huber_loss(x, y, reduction="none", delta=0.8),
                   lambda x, y: F.huber_loss(x, y, reduction="none", delta=0.8)),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_matches_torch_forward_and_gradients(name):
    inputs, torch_fn, mipnet_fn = CASES[name]
    check_op(inputs, torch_fn, mipnet_fn)


def test_batch_norm_updates_running_statistics_as_torch():
    running = [np.zeros(3, np.float32), np.ones(3, np.float32)]
    theirs = [torch.zeros(3), torch.ones(3)]
    for _ in range(2):
        out = F.batch_norm(mipnet.tensor(X), *running, training=True, momentum=0.3)
        ref = TF.batch_norm(torch.tensor(X), *theirs, training=True, momentum=0.3)
    np.testing.assert_allclose(out.numpy(), ref.numpy(), atol=1e-5, rtol=1e-4)
    for ours, t in zip(running, theirs):
        np.testing.assert_allclose(ours, t.numpy(), atol=1e-6, rtol=1e-5)


def test_the_namespace_is_torch_named_and_importable_from_nn():
    assert mipnet.nn.functional is F
    for name in F.__all__:
        assert callable(getattr(F, name)) and hasattr(TF, name), name
    assert dir(F) == sorted(F.__all__)


def test_bad_arguments_raise_argument_error():
    with pytest.raises(ArgumentError, match="reduction"):
        F.l1_loss(mipnet.tensor(X), Y, reduction="average")
    with pytest.raises(ArgumentError, match="beta"):
        F.smooth_l1_loss(mipnet.tensor(X), Y, beta=-1.0)
    with pytest.raises(ArgumentError, match="max_val"):
        F.hardtanh(mipnet.tensor(X), 1.0, -1.0)
