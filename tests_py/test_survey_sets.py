"""Survey-like under-water sets (the scene within the water's visibility) and the texture-SNR split of
``mipnet eval``; the older under-water sets keep their pairs."""

import dataclasses

import numpy as np
import pytest

from mipnet.cli import main
from mipnet.data import SceneStereo, SyntheticStereo, make_pair, make_scene
from mipnet.data.registry import DATASETS, open_dataset
from mipnet.errors import ArgumentError, InvalidValueError, ShapeError
from mipnet.stereo.evaluation import evaluate_coverages, format_table, result_rows
from mipnet.stereo.metrics import evaluate
from mipnet.underwater import PRESETS, degrade, random_water, survey_water, texture_snr, visibility
from mipnet.underwater.formation import direct_signal
from mipnet.underwater.survey import SURVEY_FAR, SURVEY_NEAR
from helpers import require

SEED = 1_000_000  # the first evaluation pair seed of `mipnet eval`
SIZE = (64, 96)
KEYS = ("left", "right", "disparity", "valid")


def _water(underwater, seed):
    """The water of pair ``seed``, written out as the generated sets document it."""
    if underwater == "random":
        return random_water(np.random.default_rng([seed, 2]))
    return PRESETS[underwater]


def _reference(generate, underwater, seed, survey=False):
    """Pair ``seed`` computed step by step from the documented recipe: the scene, its water (fitted to the scene
    for a survey), then degrade with the pair's noise seed."""
    pair = generate(*SIZE, seed)
    water = _water(underwater, seed)
    if survey:
        water = survey_water(water, pair["disparity"])
    noise = int(np.random.SeedSequence([seed, 1]).generate_state(1)[0])
    snr = texture_snr(pair["left"], pair["disparity"], water)
    pair["left"], pair["right"] = degrade(pair["left"], pair["right"], pair["disparity"], water, seed=noise)
    return pair, snr


def _snr_share(name, preset, count=8):
    """Share of the valid pixels of ``count`` pairs whose texture SNR is >= 1."""
    pairs = open_dataset(name, size=SIZE, seed=SEED, count=count, water=preset, texture_snr=True)
    seen = [(pair["texture_snr"][pair["valid"]] >= 1) for pair in pairs]
    return float(np.concatenate(seen).mean())


# ------------------------------------------------------------------------------ visibility and the range fit


def test_visibility_is_one_attenuation_length_in_daylight_and_shorter_under_a_lamp():
    for name in ("clear", "coastal", "turbid"):
        water = PRESETS[name]
        assert water.artificial_light == 0
        assert visibility(water) == pytest.approx(1.0 / water.attenuation().min(), rel=1e-9)
    lamp = PRESETS["low_light"]
    distance = visibility(lamp)
    assert 0.3 < distance < 1.0 / lamp.attenuation().min()
    # the direct signal of the channel that carries farthest is 1/e of its value at the camera there
    at_camera, there = direct_signal(lamp, np.array([0.0, distance]))
    assert np.max(there / at_camera) == pytest.approx(1.0 / np.e, rel=1e-6)


@pytest.mark.parametrize("preset", ["clear", "coastal", "turbid", "low_light"])
def test_survey_water_puts_the_farthest_pixel_at_the_visibility(preset):
    pair = make_pair(*SIZE, SEED)
    disparity = pair["disparity"].astype(np.float64)
    disparity[0, 0] = np.nan  # unknown pixels are left out of the fit
    water = survey_water(PRESETS[preset], disparity)
    far = min(visibility(PRESETS[preset]), SURVEY_FAR)
    fx = water.focal_length(SIZE[1])
    assert fx * water.baseline / np.nanmin(disparity) == pytest.approx(far, rel=1e-12)
    assert water.z_max == pytest.approx(far) and water.z_min == pytest.approx(min(SURVEY_NEAR, far / 2))
    # nothing else changed
    assert dataclasses.replace(water, baseline=PRESETS[preset].baseline, z_min=PRESETS[preset].z_min,
                               z_max=PRESETS[preset].z_max) == PRESETS[preset]


def test_survey_water_rejects_bad_disparity():
    with pytest.raises(ShapeError, match=r"survey_water.*\(5,\)"):
        survey_water(PRESETS["turbid"], np.ones(5))
    with pytest.raises(InvalidValueError, match=r"survey_water.*\(2, 3\)"):
        survey_water(PRESETS["turbid"], np.zeros((2, 3)))


# ------------------------------------------------------------------------------ the survey sets


def test_survey_sets_are_registered_under_water_and_generated():
    for name in ("survey-underwater", "scenes-survey-underwater"):
        assert DATASETS[name].kind == "generated" and DATASETS[name].underwater


@pytest.mark.parametrize("name, generate", [("survey-underwater", make_pair), ("scenes-survey-underwater", make_scene)])
@pytest.mark.parametrize("preset", ["turbid", "random"])
def test_survey_pairs_follow_the_recipe_and_depend_only_on_the_pair_seed(name, generate, preset):
    first = open_dataset(name, size=SIZE, seed=SEED, count=3, water=preset, texture_snr=True)
    again = open_dataset(name, size=SIZE, seed=SEED + 2, count=1, water=preset)[0]
    items = [first[i] for i in range(3)]
    for key in KEYS:
        np.testing.assert_array_equal(items[2][key], again[key])  # the pair seed alone decides the pair
        np.testing.assert_array_equal(items[2][key], first[2][key])
    assert not np.array_equal(items[0]["left"], items[1]["left"])
    expected, snr = _reference(generate, preset, SEED + 1, survey=True)
    for key in KEYS:
        np.testing.assert_array_equal(items[1][key], expected[key])
    np.testing.assert_array_equal(items[1]["texture_snr"], snr)
    assert items[1]["meta"]["survey"] is True and items[1]["meta"]["underwater"] == preset
    assert "texture_snr" not in again


def test_survey_sets_keep_the_scenes_and_change_only_the_water_path():
    survey = open_dataset("survey-underwater", size=SIZE, seed=SEED, count=1, water="turbid")[0]
    today = open_dataset("synthetic-underwater", size=SIZE, seed=SEED, count=1, water="turbid")[0]
    np.testing.assert_array_equal(survey["disparity"], today["disparity"])
    np.testing.assert_array_equal(survey["valid"], today["valid"])
    assert not np.array_equal(survey["left"], today["left"])


def test_survey_and_texture_snr_need_water():
    with pytest.raises(ArgumentError, match="SyntheticStereo: survey"):
        SyntheticStereo(2, 8, 8, survey=True)
    with pytest.raises(ArgumentError, match="SceneStereo: survey"):
        SceneStereo(2, 8, 8, texture_snr=True)


@pytest.mark.parametrize("preset, survey_least, today_most", [("turbid", 0.8, 0.4), ("low_light", 0.75, 0.4)])
def test_survey_pixels_mostly_keep_texture_above_the_noise(preset, survey_least, today_most):
    # measured on 8 pairs at 64x96: survey turbid 88.9%, low_light 83.5%; today's sets 26.5% and 27.6%
    assert _snr_share("survey-underwater", preset) >= survey_least
    assert _snr_share("synthetic-underwater", preset) <= today_most


# ------------------------------------------------------------------------------ today's sets are unchanged


@pytest.mark.parametrize("name, generate, preset", [
    ("synthetic-underwater", make_pair, "turbid"), ("synthetic-underwater", make_pair, "low_light"),
    ("synthetic-underwater", make_pair, "random"), ("scenes-underwater", make_scene, "random"),
])
def test_todays_sets_keep_their_pairs(name, generate, preset):
    plain = open_dataset(name, size=SIZE, seed=SEED, count=2, water=preset)
    with_snr = open_dataset(name, size=SIZE, seed=SEED, count=2, water=preset, texture_snr=True)
    for index in range(2):
        expected, snr = _reference(generate, preset, SEED + index)
        item, item_snr = plain[index], with_snr[index]
        for key in KEYS:
            np.testing.assert_array_equal(item[key], expected[key])
            np.testing.assert_array_equal(item_snr[key], expected[key])
        assert sorted(item) == ["disparity", "left", "meta", "right", "valid"] and "survey" not in item["meta"]
        assert item_snr["meta"] == item["meta"]
        np.testing.assert_array_equal(item_snr["texture_snr"], snr)


# ------------------------------------------------------------------------------ the split rows


def test_evaluation_splits_the_pixels_by_texture_snr():
    pair = make_pair(*SIZE, 3)
    rng = np.random.default_rng(0)
    pair["texture_snr"] = rng.uniform(0.0, 2.0, SIZE).astype(np.float32)
    guess = pair["disparity"] + rng.normal(0.0, 2.0, SIZE).astype(np.float32)
    holes = rng.random(SIZE) < 0.2
    result = evaluate_coverages([pair], lambda left, right: (guess, ~holes), ("full", "covered"))
    valid = pair["valid"]
    for band, mask in (("texture SNR >= 1", pair["texture_snr"] >= 1), ("texture SNR < 1", pair["texture_snr"] < 1)):
        full, covered = result["full"]["bands"][band], result["covered"]["bands"][band]
        assert full["share"] == pytest.approx(100.0 * (valid & mask).sum() / valid.sum())
        assert full["pooled"]["epe"] == pytest.approx(evaluate(np.where(holes, 0.0, guess), pair["disparity"],
                                                               valid & mask)["epe"])
        assert covered["pooled"]["epe"] == pytest.approx(evaluate(guess, pair["disparity"], valid & mask & ~holes)["epe"])
        assert covered["coverage"] == pytest.approx(100.0 * (valid & mask & ~holes).sum() / (valid & mask).sum())
    rows = result_rows("SGBM (covered)", result["covered"], "pooled", snr_split=True)
    assert [row["method"] for row in rows] == ["SGBM (covered)", "SGBM (covered), texture SNR >= 1",
                                               "SGBM (covered), texture SNR < 1"]
    assert rows[0]["share"] == 100.0 and sum(row["share"] for row in rows[1:]) == pytest.approx(100.0)
    assert "share" in [cell.strip() for cell in format_table(rows).splitlines()[0].split("|")]
    assert len(result_rows("x", result["full"])) == 1  # the split is asked for
    pair["texture_snr"] = pair["texture_snr"][1:]
    with pytest.raises(ShapeError, match=r"evaluate_coverages: texture_snr \(63, 96\).*\(64, 96\)"):
        evaluate_coverages([pair], lambda left, right: guess, ("dense",))


def _table(out):
    """The printed table: method -> {column: cell}."""
    lines = [line for line in out.splitlines() if line.startswith("|")]
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    return {cells[0]: dict(zip(header, cells)) for cells in
            ([cell.strip() for cell in line.strip("|").split("|")] for line in lines[2:])}


def test_eval_prints_the_snr_split_on_a_survey_set(capsys):
    assert main(["eval", "--dataset", "survey-underwater", "--preset", "turbid", "--n", "2", "--size", "64", "96",
                 "--methods", "mipnet", "--iters", "1", "1"]) == 0
    out = capsys.readouterr().out
    table = _table(out)
    assert list(table) == ["MIPNet", "MIPNet, texture SNR >= 1", "MIPNet, texture SNR < 1"]
    assert float(table["MIPNet"]["share"]) == 100.0
    shares = [float(table[f"MIPNet, texture SNR {band}"]["share"]) for band in (">= 1", "< 1")]
    assert sum(shares) == pytest.approx(100.0, abs=0.01) and shares[0] > 50
    assert "texture-SNR band" in out


def test_eval_splits_sgbm_on_todays_sets_and_not_in_air(capsys):
    require("cv2")
    args = ["--n", "2", "--size", "64", "96", "--methods", "sgbm"]
    assert main(["eval", "--dataset", "synthetic-underwater", "--preset", "turbid", *args]) == 0
    table = _table(capsys.readouterr().out)
    assert list(table) == [f"SGBM ({kind}){band}" for kind in ("full coverage", "covered")
                           for band in ("", ", texture SNR >= 1", ", texture SNR < 1")]
    assert main(["eval", "--dataset", "synthetic", *args]) == 0
    out = capsys.readouterr().out
    assert list(_table(out)) == ["SGBM (full coverage)", "SGBM (covered)"] and "share" not in out
