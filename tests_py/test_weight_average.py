"""mipnet.training.average.WeightAverage: the moving average of a model's parameters."""

import numpy as np
import pytest

import mipnet
from mipnet.errors import ArgumentError
from mipnet.training.average import WeightAverage


def _model():
    mipnet.manual_seed(0)
    return mipnet.nn.Sequential(mipnet.nn.Conv2d(3, 4, 3), mipnet.nn.BatchNorm2d(4))


def test_the_average_follows_the_recurrence_in_float64():
    model, decay = _model(), 0.8
    params = dict(model.named_parameters())
    expected = {n: p.data.astype(np.float64) for n, p in params.items()}
    average = WeightAverage(model, decay)
    rng = np.random.default_rng(1)
    for _ in range(20):
        for name, p in params.items():
            p.data[...] += rng.normal(0, 0.1, p.data.shape).astype(np.float32)
            expected[name] = decay * expected[name] + (1 - decay) * p.data.astype(np.float64)
        average.update()
    for name, value in average.state_dict().items():
        np.testing.assert_allclose(value, expected[name], rtol=0, atol=1e-6, err_msg=name)


def test_applied_swaps_the_average_in_and_restores_the_weights_bitwise():
    model = _model()
    average = WeightAverage(model, 0.5)
    params = dict(model.named_parameters())
    for p in params.values():
        p.data[...] = p.data * 3 + 1
    average.update()
    before = {n: p.data.copy() for n, p in params.items()}
    with average.applied():
        for name, p in params.items():
            np.testing.assert_array_equal(p.data, average.values[name])
    for name, p in params.items():
        np.testing.assert_array_equal(p.data, before[name])


def test_a_decay_outside_zero_one_and_a_foreign_state_raise():
    with pytest.raises(ArgumentError, match="decay"):
        WeightAverage(_model(), 1.0)
    average = WeightAverage(_model(), 0.9)
    with pytest.raises(ArgumentError, match="missing"):
        average.load_state_dict({"0.weight": np.zeros((4, 3, 3, 3), np.float32)})
    state = average.state_dict()
    state["0.weight"] = np.zeros((1, 3, 3, 3), np.float32)
    with pytest.raises(ArgumentError, match="shape"):
        average.load_state_dict(state)
