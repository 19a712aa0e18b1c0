"""mipnet.match_confidence: the correlation of the two views' detail at a disparity (what `infer --min-confidence` masks)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mipnet
from mipnet.data.synthetic import make_pair
from mipnet.errors import ArgumentError, ShapeError
from mipnet.underwater import degrade


def textured_pair(height=64, width=96, shift=6, seed=0):
    """A random-texture pair whose right view is the left shifted by ``shift`` px (disparity ``shift`` everywhere)."""
    rng = np.random.default_rng(seed)
    scene = rng.uniform(0, 255, (height, width + shift, 3))
    return scene[:, :width], scene[:, shift:], np.full((height, width), float(shift), np.float32)


def test_the_true_disparity_is_confident_and_a_wrong_one_is_not():
    left, right, disparity = textured_pair()
    seen = np.arange(96)[None, :] >= 6 + 15  # the match and its whole window inside the right view
    right_answer = mipnet.match_confidence(left, right, disparity)
    wrong_answer = mipnet.match_confidence(left, right, disparity + 5)
    assert right_answer[:, seen[0]].min() > 0.9  # not 1: the blurs reflect different content at the borders
    assert abs(wrong_answer[:, seen[0]].mean()) < 0.1 and (wrong_answer[:, seen[0]] > 0.5).mean() < 0.02


def test_independent_noise_stays_near_zero_within_the_stated_spread():
    rng = np.random.default_rng(1)
    left, right = rng.normal(128, 20, (2, 200, 200, 3))
    for window in (9, 15):
        confidence = mipnet.match_confidence(left, right, np.zeros((200, 200)), window=window)
        assert abs(confidence.mean()) < 0.03 and confidence.std() < 2.5 / window * 1.1


def test_gain_and_offset_between_the_cameras_do_not_change_it():
    left, right, disparity = textured_pair(seed=2)
    noisy = right + np.random.default_rng(3).normal(0, 40, right.shape)
    np.testing.assert_allclose(mipnet.match_confidence(left, 0.5 * noisy + 40, disparity),
                               mipnet.match_confidence(left, noisy, disparity), atol=1e-4)


def test_matches_outside_the_right_view_and_non_finite_disparities_score_zero():
    left, right, disparity = textured_pair(seed=4)
    disparity[:, 40] = 41.0  # x - d = -1
    disparity[:, 50] = np.nan
    confidence = mipnet.match_confidence(left, right, disparity)
    assert (confidence[:, :6] == 0).all() and (confidence[:, 40] == 0).all() and (confidence[:, 50] == 0).all()


def test_grey_images_and_colour_images_agree():
    left, right, disparity = textured_pair(seed=5)
    np.testing.assert_allclose(mipnet.match_confidence(left.mean(axis=2), right.mean(axis=2), disparity),
                               mipnet.match_confidence(left, right, disparity), atol=1e-5)


def test_open_water_under_a_veil_is_told_from_the_textured_objects_in_front():
    pair = make_pair(192, 256, seed=8)
    valid = pair["valid"]
    far = valid & (pair["disparity"] < np.median(pair["disparity"][valid]))
    open_water = np.where(far, 0.0, pair["disparity"])  # disparity 0: beyond the water's reach, pure veil
    left, right = degrade(pair["left"], pair["right"], open_water, "turbid", seed=1)
    confidence = mipnet.match_confidence(left, right, pair["disparity"])
    near = valid & ~far
    # much of the near objects' texture drowns too (turbid water), but the veil alone almost never passes 0.5
    kept_far, kept_near = (confidence[far] >= 0.5).mean(), (confidence[near] >= 0.5).mean()
    assert kept_far < 0.15 and kept_near > 2 * kept_far


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 40), st.integers(1, 40), st.integers(0, 2**31 - 1), st.sampled_from([1, 3, 15]))
def test_any_input_gives_a_finite_map_in_minus_one_to_one(height, width, seed, window):
    rng = np.random.default_rng(seed)
    left, right = rng.integers(0, 256, (2, height, width, 3), dtype=np.uint8)
    disparity = rng.uniform(-5, width + 5, (height, width)).astype(np.float32)
    confidence = mipnet.match_confidence(left, right, disparity, window=window)
    assert confidence.shape == (height, width) and confidence.dtype == np.float32
    assert np.isfinite(confidence).all() and (np.abs(confidence) <= 1).all()


@pytest.mark.parametrize("args, error, text", [
    ((np.zeros((8, 8, 3)), np.zeros((8, 9, 3)), np.zeros((8, 8))), ShapeError, "right (8, 9, 3)"),
    ((np.zeros((8, 8, 3)), np.zeros((8, 8, 3)), np.zeros((8, 7))), ShapeError, "disparity (8, 7)"),
    ((np.zeros((8,)), np.zeros((8,)), np.zeros((8,))), ShapeError, "left (8,)"),
])
def test_shape_errors_name_the_function_and_the_shapes(args, error, text):
    with pytest.raises(error, match="match_confidence") as info:
        mipnet.match_confidence(*args)
    assert text in str(info.value) and isinstance(info.value, RuntimeError)


def test_non_finite_or_non_numeric_images_are_argument_errors():
    left, right, disparity = textured_pair()
    left[3, 4, 1] = np.nan
    with pytest.raises(ArgumentError, match="match_confidence: left image .* NaN or inf"):
        mipnet.match_confidence(left, right, disparity)
    with pytest.raises(ArgumentError, match="right image has unsupported dtype"):
        mipnet.match_confidence(right, right.astype(str), disparity)


@pytest.mark.parametrize("options, text", [({"window": 4}, "window"), ({"window": 0}, "window"),
                                           ({"noise_sigma": 3.0, "shading_sigma": 2.0}, "noise_sigma")])
def test_bad_options_are_argument_errors(options, text):
    image = np.zeros((8, 8, 3))
    with pytest.raises(ArgumentError, match=text):
        mipnet.match_confidence(image, image, np.zeros((8, 8)), **options)
