"""Warm start: ``MIPNet.forward_with_state`` (the state a pass ends in and starts from) and ``mipnet.Stream`` (video
frames from the previous frame's state, cold on the first frame and after a reset)."""

import numpy as np
import pytest

import mipnet
from mipnet.data.sequences import make_sequence
from mipnet.errors import ArgumentError, ShapeError
from mipnet.model.state import NetworkState
from mipnet.model.stream import CARRY_CHOICES
from mipnet.stereo.temporal import score_sequence, summarise_frames

SIZE = (64, 96)


@pytest.fixture(scope="module")
def model():
    return mipnet.MIPNet.pretrained()


@pytest.fixture(scope="module")
def frames():
    return make_sequence(1_000_001, frames=4, size=SIZE)


def test_forward_with_state_without_init_is_the_forward_pass(model, frames):
    left, right = frames[0]["left"], frames[0]["right"]
    disp, state = model.forward_with_state(left, right, iters=(2, 1))
    np.testing.assert_array_equal(disp, model(left, right, iters=(2, 1)))
    # padded 64x96: 1/16 is 4x6, 1/4 is 16x24
    assert state.flow16.shape == (1, 2, 4, 6) and state.hidden16.shape == (1, 128, 4, 6)
    assert state.flow4.shape == (1, 2, 16, 24) and state.hidden4.shape == (1, 128, 16, 24)
    assert np.all(state.flow16[:, 1] == 0) and np.all(state.flow4[:, 1] == 0)  # the vertical constraint
    # the final 1/4 field is the output's disparity at a quarter of the resolution
    assert abs(float(state.disparity4().mean()) - float(disp.mean())) < 0.05 * float(disp.mean())
    _, only16 = model.forward_with_state(left, right, iters=(1, 0))
    assert only16.flow4 is None and only16.hidden4 is None


def test_each_piece_of_init_replaces_its_cold_start(model, frames):
    left, right = frames[0]["left"], frames[0]["right"]
    disp, _ = model.forward_with_state(left, right, iters=(1, 1), init=NetworkState())
    np.testing.assert_array_equal(disp, model(left, right, iters=(1, 1)))
    # the 1/16 field of init is the initial field disp_init gives (disp_init: positive 1/16-level disparities)
    d0 = np.random.default_rng(0).uniform(0.5, 4.0, (1, 1, 4, 6)).astype(np.float32)
    flow16 = np.concatenate([-d0, np.zeros_like(d0)], axis=1)
    disp, _ = model.forward_with_state(left, right, iters=(1, 1), init=NetworkState(flow16=flow16))
    np.testing.assert_array_equal(disp, model(left, right, iters=(1, 1), disp_init=d0))
    # a carried 1/4 field replaces the hand-over: the 1/16 level no longer changes the output
    _, state = model.forward_with_state(left, right, iters=(2, 2))
    a, _ = model.forward_with_state(left, right, iters=(1, 1), init=NetworkState(flow4=state.flow4))
    b, _ = model.forward_with_state(left, right, iters=(3, 1), init=NetworkState(flow4=state.flow4))
    np.testing.assert_array_equal(a, b)
    c, _ = model.forward_with_state(left, right, iters=(1, 1), init=state.select(["flow4", "hidden4"]))
    assert not np.array_equal(a, c)  # the hidden state changes what the iteration does


def test_a_bad_init_is_one_clear_error(model, frames):
    left, right = frames[0]["left"], frames[0]["right"]
    with pytest.raises(ShapeError, match=r"init.hidden4 must have shape \[1, 128, 16, 24\]"):
        model.forward_with_state(left, right, init=NetworkState(hidden4=np.zeros((1, 128, 8, 12), np.float32)))
    with pytest.raises(ArgumentError, match="init.flow16 contains NaN"):
        model.forward_with_state(left, right, init=NetworkState(flow16=np.full((1, 2, 4, 6), np.nan, np.float32)))
    with pytest.raises(ArgumentError, match="unknown piece"):
        NetworkState().select(["flow8"])
    trained = mipnet.MIPNet().train()
    with pytest.raises(ArgumentError, match="eval mode"):
        trained.forward_with_state(left, right)


def test_the_first_frame_and_every_reset_frame_equal_a_cold_forward(model, frames):
    stream = mipnet.Stream(model, (1, 1), cold_iters=(2, 1))
    cold = [model(f["left"], f["right"], iters=(2, 1)) for f in frames[:3]]
    np.testing.assert_array_equal(stream(frames[0]["left"], frames[0]["right"]), cold[0])
    warm = stream(frames[1]["left"], frames[1]["right"])
    assert not np.array_equal(warm, cold[1]) and stream.resets == []
    stream.reset()
    np.testing.assert_array_equal(stream(frames[2]["left"], frames[2]["right"]), cold[2])
    # a threshold below any ratio resets every frame: each is the cold forward
    always = mipnet.Stream(model, (1, 1), cold_iters=(2, 1), reset=1e-6)
    for frame, expected in zip(frames[:3], cold):
        np.testing.assert_array_equal(always(frame["left"], frame["right"]), expected)
    assert always.resets == [1, 2] and np.all(np.array(always.ratios[1:]) > 1e-6)
    # a new image size starts cold
    np.testing.assert_array_equal(stream(frames[0]["left"][:48], frames[0]["right"][:48]),
                                  model(frames[0]["left"][:48], frames[0]["right"][:48], iters=(2, 1)))


def test_a_cut_resets_and_the_cut_frame_is_the_cold_forward(model):
    # at 128x192 the photometric check tells a new scene from the camera's motion (docs/video.md)
    cut = make_sequence(1_000_002, frames=3, size=(128, 192), cut_at=2)
    stream = mipnet.Stream(model, (1, 1), cold_iters=(1, 1))
    outputs = [stream(f["left"], f["right"]) for f in cut]
    assert stream.resets == [2], stream.ratios
    np.testing.assert_array_equal(outputs[2], model(cut[2]["left"], cut[2]["right"], iters=(1, 1)))


def test_warm_start_is_not_worse_than_cold_at_equal_iterations(model, frames):
    iters = (1, 1)
    cold = summarise_frames([score_sequence(frames, lambda l, r: model(l, r, iters=iters))[1:]])["all"]
    warm = summarise_frames([score_sequence(frames, mipnet.Stream(model, iters, cold_iters=iters))[1:]])["all"]
    assert warm["epe"] <= cold["epe"], (warm, cold)


def test_bad_stream_arguments_are_one_clear_error(model, frames):
    with pytest.raises(ArgumentError, match="training mode"):
        mipnet.Stream(mipnet.MIPNet().train())
    with pytest.raises(ArgumentError, match="unknown carry"):
        mipnet.Stream(model, carry=("flow8",))
    with pytest.raises(ArgumentError, match="not both"):
        mipnet.Stream(model, carry=("flow16", "pooled16"))
    with pytest.raises(ArgumentError, match="reset"):
        mipnet.Stream(model, reset=0)
    with pytest.raises(ArgumentError, match="iters"):
        mipnet.Stream(model, iters=(0, 2))
    with pytest.raises(ShapeError, match="one frame"):
        mipnet.Stream(model)(np.zeros((2, 3, 64, 96)), np.zeros((2, 3, 64, 96)))
    assert set(mipnet.model.stream.DEFAULT_CARRY) <= set(CARRY_CHOICES)
