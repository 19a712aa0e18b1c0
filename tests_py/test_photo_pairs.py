"""Stereo pairs made from single real photographs (mipnet.data.photo_pairs, mipnet.data.photographs)."""

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage
from helpers import require

from mipnet.data import PhotoStereo, make_photo_pair, photographs
from mipnet.data.registry import open_dataset, parse_spec
from mipnet.data.synthetic import EVAL_SEED_START
from mipnet.errors import ArgumentError
from mipnet.stereo.io import write_image

require("skimage")


def right_at_left_positions(pair, shift=0.0):
    """The right view sampled at (x - d + shift, y) for every left pixel (linear in x)."""
    d = pair["disparity"].astype(np.float64)
    rows, cols = np.indices(d.shape)
    x = np.clip(cols - d + shift, 0, d.shape[1] - 1.001)
    x0 = np.floor(x).astype(int)
    t = (x - x0)[..., None]
    right = pair["right"].astype(np.float64)
    return (1 - t) * right[rows, x0] + t * right[rows, x0 + 1]


def test_a_pair_is_a_deterministic_function_of_size_and_seed():
    a, b = make_photo_pair(64, 96, 11), make_photo_pair(64, 96, 11)
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(a[key], b[key])
    c = make_photo_pair(64, 96, 12)
    assert not np.array_equal(a["disparity"], c["disparity"])


@pytest.mark.parametrize("seed", [0, 3, 8])
def test_valid_left_pixels_are_seen_in_the_right_view_at_their_disparity(seed):
    pair = make_photo_pair(96, 160, seed, clean=True)
    d, valid = pair["disparity"], pair["valid"]
    assert d.dtype == np.float32 and d.min() >= 0.25 and d.max() <= 160 / 4
    error = np.abs(right_at_left_positions(pair) - pair["left"]).mean(axis=-1)
    # photometric agreement where the left pixel is seen; the few misses are mixed pixels on depth edges
    assert np.median(error[valid]) < 4.0
    assert np.mean(error[valid] > 25) < 0.1
    # where the right camera cannot see the left pixel (it projects outside), valid is False
    rows, cols = np.indices(d.shape)
    assert not valid[cols - d < 0].any()


def test_the_views_align_best_at_the_ground_truth_to_a_tenth_of_a_pixel():
    """A sub-pixel bias of the ground truth (say half a pixel) would teach every network trained on these pairs
    that bias: over pairs, the photometric error must be smallest at exactly x - d. (One pair's minimum can sit
    0.1 px off without a bias: both views and this test interpolate linearly, and a fine texture's error curve
    is flat near its minimum.)"""
    pairs = [make_photo_pair(96, 160, seed, clean=True) for seed in range(6)]

    def mean_error(shift):
        errors = []
        for pair in pairs:
            # the surfaces' interiors: valid, no depth edge or mixed pixel beside them (|dd/dx| < 0.05)
            interior = pair["valid"] & (np.abs(np.gradient(pair["disparity"], axis=1)) < 0.05)
            errors.append(np.abs(right_at_left_positions(pair, shift) - pair["left"]).mean(axis=-1)[interior])
        return np.concatenate(errors).mean()

    at_truth = mean_error(0.0)
    assert at_truth < mean_error(-0.1) and at_truth < mean_error(0.1)


def test_disparities_are_scaled_into_range_not_clipped_into_plateaus():
    """A layout that ran past max_disparity used to be clipped there: flat plateaus of one disparity over
    whole textured surfaces, a shape real scenes do not have."""
    for seed in range(6):
        pair = make_photo_pair(96, 160, seed)
        d = pair["disparity"][pair["valid"]]
        assert d.max() <= 160 / 4 + 1e-4
        assert np.mean(d >= 160 / 4 - 1e-3) < 0.01


def test_blank_areas_have_no_ground_truth(tmp_path, monkeypatch):
    """Deep inside a blank area no view reveals the disparity: such pixels are not valid."""
    rng = np.random.default_rng(1)
    photo = np.full((120, 180, 3), 255, np.uint8)
    photo[:, :90] = (rng.random((120, 90, 3)) * 255).astype(np.uint8)
    write_image(tmp_path / "half_blank.png", photo)
    monkeypatch.setattr(photographs, "names", lambda held_out=False: ["tmp/half_blank.png"])
    monkeypatch.setattr(photographs, "load", lambda name: Image.open(tmp_path / "half_blank.png").convert("RGB"))
    for seed in range(3):
        pair = make_photo_pair(96, 160, seed, clean=True)
        luma = pair["left"].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
        textured = np.zeros(luma.shape, bool)
        textured[:, :-1] |= np.abs(np.diff(luma, axis=1)) > 4
        textured[:-1] |= np.abs(np.diff(luma, axis=0)) > 4
        far = ndimage.distance_transform_edt(~textured) > 9
        assert far.any() and not (pair["valid"] & far).any()
        assert pair["valid"][~far].mean() > 0.3


def test_depth_edges_lie_on_the_photographs_edges():
    """Disparity steps follow the photograph's segments: the colour changes across most of them."""
    shares = []
    for seed in range(4):
        pair = make_photo_pair(96, 160, seed, clean=True)
        d, left = pair["disparity"], pair["left"].astype(np.float64)
        steps = np.abs(np.diff(d, axis=1)) > 1.0
        colour = np.abs(np.diff(left, axis=1)).sum(axis=-1)
        if steps.sum() >= 20:
            shares.append(np.mean(colour[steps] > np.median(colour)))
    assert shares and np.mean(shares) > 0.75


def test_training_seeds_use_training_photographs_and_evaluation_seeds_held_out_ones():
    held_out = set(photographs.names(held_out=True))
    training = set(photographs.names())
    assert held_out and training and not held_out & training
    assert all(make_photo_pair(48, 64, seed)["meta"]["photo"] in training for seed in range(4))
    assert all(make_photo_pair(48, 64, EVAL_SEED_START + s)["meta"]["photo"] in held_out for s in range(4))


def test_a_folder_of_the_users_photographs_joins_the_collection(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    folder = tmp_path / "mine"
    folder.mkdir()
    for i in range(12):
        write_image(folder / f"shot{i}.png", (rng.random((80, 120, 3)) * 255).astype(np.uint8))
    monkeypatch.setenv(photographs.ENV_VARIABLE, str(folder))
    every = photographs.names() + photographs.names(held_out=True)
    assert sum(name.startswith("mine/") for name in every) == 12
    assert photographs.load("mine/shot3.png").size == (120, 80)
    assert any(source.endswith(str(folder)) for source in photographs.sources())
    monkeypatch.setenv(photographs.ENV_VARIABLE, str(tmp_path / "missing"))
    with pytest.raises(ArgumentError, match="MIPNET_PHOTOS"):
        photographs.names()


def test_the_registry_offers_photo_pairs_in_air_and_under_water():
    assert parse_spec("photos:0.3").weight == 0.3
    pair = open_dataset("photos-underwater", size=(48, 64), seed=5, count=2)[1]
    assert pair["left"].shape == (48, 64, 3) and pair["meta"]["underwater"] == "random"
    assert pair["meta"]["photo"] in photographs.names()
    assert isinstance(open_dataset("photos", size=(48, 64), seed=EVAL_SEED_START, count=1), PhotoStereo)


def test_bad_arguments_name_the_function():
    with pytest.raises(ArgumentError, match="make_photo_pair"):
        make_photo_pair(48, 64, 0, max_disparity=0)
    with pytest.raises(ArgumentError, match="make_photo_pair"):
        make_photo_pair(48, 64, -1)
