"""Procedural stereo pairs (exact disparity), underwater degradation, and SGBM on degraded pairs."""

import time

import numpy as np
import pytest
from helpers import require, sample_right
from mipnet.data import SyntheticStereo, make_pair, synthetic_underwater_pairs
from mipnet.stereo.metrics import evaluate
from mipnet.underwater import (
    PRESETS,
    WaterParams,
    degrade,
    linear_to_srgb,
    srgb_to_linear,
    texture_snr,
)
from mipnet.errors import ArgumentError, ShapeError


def require_cv2():
    """cv2 is optional for users; required in CI (see helpers.require)."""
    return require("cv2")


@pytest.fixture(scope="module")
def pair():
    return make_pair(96, 128, seed=5)


# ------------------------------------------------------------------------------ synthetic


def test_make_pair_types_and_determinism(pair):
    assert pair["left"].shape == pair["right"].shape == (96, 128, 3)
    assert pair["left"].dtype == pair["right"].dtype == np.uint8
    assert pair["disparity"].shape == (96, 128) and pair["disparity"].dtype == np.float32
    assert pair["valid"].dtype == bool
    again = make_pair(96, 128, seed=5)
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(pair[key], again[key])
    other = make_pair(96, 128, seed=6)
    assert not np.array_equal(pair["left"], other["left"])
    assert not np.array_equal(pair["disparity"], other["disparity"])


def test_make_pair_disparity_is_exact_photometrically(pair):
    error = np.abs(sample_right(pair["right"], pair["disparity"])[0] - pair["left"]).mean(axis=2)
    valid = pair["valid"]
    assert error[valid].mean() < 2.0  # grey levels, linear interpolation of a smooth texture
    assert np.percentile(error[valid], 95) < 5.0
    # shifting the disparity by 2 px must make the match clearly worse
    shifted = np.abs(sample_right(pair["right"], pair["disparity"] + 2)[0] - pair["left"]).mean(axis=2)
    assert shifted[valid].mean() > 3 * error[valid].mean()


def test_make_pair_disparity_range_and_valid_mask(pair):
    d, valid = pair["disparity"], pair["valid"]
    width = d.shape[1]
    assert d.min() > 0 and d.max() <= 1.25 * width / 8 + 1e-3
    assert 0.5 < valid.mean() < 1.0  # some occlusion and border pixels, mostly visible
    x = np.arange(width)[None, :]
    assert not valid[x - d < 0].any()  # projects outside the right image


def test_make_pair_odd_sizes_and_speed():
    for height, width in ((1, 1), (7, 13), (33, 5)):
        p = make_pair(height, width, seed=1)
        assert p["left"].shape == (height, width, 3) and p["disparity"].shape == (height, width)
        assert np.isfinite(p["disparity"]).all()
    timings = []
    for seed in range(2):
        start = time.perf_counter()
        make_pair(384, 512, seed=seed)
        timings.append(time.perf_counter() - start)
    assert min(timings) < 0.5


def test_synthetic_dataset_and_underwater_option():
    clean = SyntheticStereo(3, 48, 64, seed=2)
    murky = SyntheticStereo(3, 48, 64, seed=2, underwater="turbid")
    assert len(clean) == 3
    a, b = clean[1], murky[1]
    np.testing.assert_array_equal(a["disparity"], b["disparity"])
    np.testing.assert_array_equal(a["valid"], b["valid"])
    assert not np.array_equal(a["left"], b["left"])
    np.testing.assert_array_equal(murky[1]["left"], b["left"])
    assert not np.array_equal(clean[0]["left"], clean[1]["left"])
    assert b["meta"]["underwater"] == "turbid" and a["meta"]["underwater"] is None
    custom = SyntheticStereo(1, 48, 64, underwater={"preset": "clear", "gain": 0.5})[0]
    assert custom["meta"]["underwater"] == "clear"
    pairs = synthetic_underwater_pairs(2, 48, 64, "low_light", seed=2)
    assert len(pairs) == 2 and pairs[0]["left"].mean() < clean[0]["left"].mean()


# ----------------------------------------------------------------------------- underwater


def _contrast(image):
    gray = image.astype(np.float64).mean(axis=2)
    return gray.std() / gray.mean()


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_degrade_presets_deterministic_per_seed(pair, preset):
    left, right = degrade(pair["left"], pair["right"], pair["disparity"], preset=preset, seed=3)
    assert left.shape == right.shape == (96, 128, 3) and left.dtype == right.dtype == np.uint8
    again = degrade(pair["left"], pair["right"], pair["disparity"], preset=preset, seed=3)
    np.testing.assert_array_equal(left, again[0])
    np.testing.assert_array_equal(right, again[1])
    other = degrade(pair["left"], pair["right"], pair["disparity"], preset=preset, seed=4)
    assert not np.array_equal(left, other[0]) and not np.array_equal(right, other[1])
    assert not np.array_equal(left, pair["left"])


def test_degrade_leaves_inputs_untouched(pair):
    copies = {k: pair[k].copy() for k in ("left", "right", "disparity")}
    degrade(pair["left"], pair["right"], pair["disparity"], "turbid", seed=0)
    for key, value in copies.items():
        np.testing.assert_array_equal(pair[key], value)


def test_turbid_reduces_contrast_and_low_light_darkens(pair):
    clean = _contrast(pair["left"])
    turbid, _ = degrade(pair["left"], pair["right"], pair["disparity"], "turbid", seed=0)
    clear, _ = degrade(pair["left"], pair["right"], pair["disparity"], "clear", seed=0)
    dark, _ = degrade(pair["left"], pair["right"], pair["disparity"], "low_light", seed=0)
    assert _contrast(turbid) < 0.5 * clean
    assert _contrast(turbid) < _contrast(clear)
    assert dark.mean() < 0.5 * pair["left"].mean()


def test_degrade_views_share_the_water(pair):
    # Noise aside, both views of one scene get the same colour cast.
    left, right = degrade(pair["left"], pair["right"], pair["disparity"], "coastal", seed=0)
    np.testing.assert_allclose(left.reshape(-1, 3).mean(0), right.reshape(-1, 3).mean(0), atol=8)
    assert left[..., 1].mean() > left[..., 0].mean()  # coastal water is green, red is absorbed


def test_degrade_parameter_overrides(pair):
    args = (pair["left"], pair["right"], pair["disparity"])
    base, _ = degrade(*args, "coastal", seed=0)
    dim, _ = degrade(*args, "coastal", seed=0, gain=0.3)
    assert dim.mean() < base.mean()
    params = WaterParams(water_type="9C", marine_snow=0.0)
    own, _ = degrade(*args, preset=params, seed=0)
    assert own.shape == base.shape
    with pytest.raises(TypeError, match="unknown water parameter"):
        degrade(*args, "coastal", turbidity=3)
    with pytest.raises(ValueError, match="unknown underwater preset"):
        degrade(*args, "swamp")
    with pytest.raises(ValueError, match="Jerlov"):
        degrade(*args, "coastal", water_type="42X")
    with pytest.raises(ValueError):
        degrade(pair["left"], pair["right"][:10], pair["disparity"])


def test_degrade_handles_invalid_disparity(pair):
    disparity = pair["disparity"].copy()
    disparity[:10] = 0
    disparity[10:20] = np.nan
    left, right = degrade(pair["left"], pair["right"], disparity, "turbid", seed=0)
    assert left.shape == (96, 128, 3)


def _detail(image):
    """Luminance minus its 9x9 box mean (the fine detail, as texture_snr's blur of sigma 3 px), from row and column 1."""
    linear = srgb_to_linear(image).mean(axis=2)
    blur = np.cumsum(np.cumsum(np.pad(linear, 4, mode="edge"), 0), 1)
    # 9x9 box sum over padded rows i+1..i+9 (image row i+1) from the summed-area table: S[i+9] - S[i], per axis
    box = (blur[9:, 9:] - blur[:-9, 9:] - blur[9:, :-9] + blur[:-9, :-9]) / 81.0
    return linear[1:, 1:] - box


@pytest.mark.parametrize("seed", [5, 7])
@pytest.mark.parametrize("preset", ["turbid", "low_light"])
def test_texture_snr_says_where_two_noise_draws_agree(seed, preset):
    # What two cameras can match is the detail that repeats across independent noise draws: where the SNR
    # is high the degraded views' detail agrees between draws, where it is far below 1 it does not.
    pair = make_pair(96, 128, seed=seed)
    snr = texture_snr(pair["left"], pair["disparity"], preset)[1:, 1:]
    one, _ = degrade(pair["left"], pair["right"], pair["disparity"], preset, seed=0)
    two, _ = degrade(pair["left"], pair["right"], pair["disparity"], preset, seed=1)
    a, b = _detail(one), _detail(two)
    seen, hidden = snr > 3, snr < 0.3
    assert seen.sum() > 500 and hidden.sum() > 500
    assert np.corrcoef(a[seen], b[seen])[0, 1] > 0.5
    assert abs(np.corrcoef(a[hidden], b[hidden])[0, 1]) < 0.1


def test_texture_snr_falls_with_range_and_needs_texture(pair):
    near, far = np.full((96, 128), 24.0), np.full((96, 128), 4.0)
    assert np.median(texture_snr(pair["left"], near, "turbid")) > 4 * np.median(texture_snr(pair["left"], far, "turbid"))
    assert np.median(texture_snr(pair["left"], near, "clear")) > 10
    flat = np.full_like(pair["left"], 120)
    assert texture_snr(flat, near, "clear").max() < 1e-3
    more_light = texture_snr(pair["left"], far, "low_light", full_well=3000.0)
    assert np.median(more_light) > np.median(texture_snr(pair["left"], far, "low_light"))


def test_texture_snr_rejects_bad_input(pair):
    with pytest.raises(ShapeError, match=r"texture_snr.*\(96, 128, 3\).*\(10, 128\)"):
        texture_snr(pair["left"], pair["disparity"][:10])
    with pytest.raises(ArgumentError, match="texture_snr: window"):
        texture_snr(pair["left"], pair["disparity"], window=4)


def test_srgb_round_trip():
    values = np.arange(256, dtype=np.uint8)
    np.testing.assert_array_equal(linear_to_srgb(srgb_to_linear(values)), values)


# ---------------------------------------------------------------------------------- SGBM


@pytest.mark.parametrize("preset", ["turbid", "low_light"])
def test_sgbm_on_degraded_pairs_gives_finite_epe(pair, preset):
    require_cv2()
    from mipnet.stereo.baselines import sgbm

    left, right = degrade(pair["left"], pair["right"], pair["disparity"], preset, seed=0)
    disparity, valid = sgbm(left, right)
    assert disparity.shape == (96, 128) and disparity.dtype == np.float32 and valid.dtype == bool
    assert np.all(disparity[~valid] == 0)
    full = evaluate(np.where(valid, disparity, 0), pair["disparity"], pair["valid"])
    assert np.isfinite(full["epe"]) and full["n"] > 0


def test_sgbm_on_clean_pair_is_accurate(pair):
    require_cv2()
    from mipnet.stereo.baselines import default_num_disparities, sgbm

    assert default_num_disparities(128) == 32 and default_num_disparities(10) == 16
    disparity, valid = sgbm(pair["left"], pair["right"])
    covered = evaluate(disparity, pair["disparity"], pair["valid"] & valid)
    assert covered["epe"] < 1.5 and valid.mean() > 0.3


def test_sgbm_rows_and_table():
    require_cv2()
    from mipnet.stereo.evaluation import format_table, sgbm_rows

    rows = sgbm_rows(synthetic_underwater_pairs(2, 64, 96, "turbid", seed=0))
    assert [r["method"] for r in rows] == ["SGBM (full coverage)", "SGBM (covered)"]
    assert rows[0]["coverage"] == rows[1]["coverage"] and 0 <= rows[0]["coverage"] <= 100
    assert rows[0]["n"] >= rows[1]["n"] and rows[0]["images"] == 2
    assert "SGBM (covered)" in format_table(rows)
