"""mipnet.stereo.metrics on hand-computed cases, and mipnet.stereo.evaluation's loop and tables."""

import math

import numpy as np
import pytest
from mipnet.errors import ShapeError
from mipnet.stereo.evaluation import evaluate_method, format_table, mipnet_rows, result_row
from mipnet.stereo.metrics import METRIC_KEYS, MetricAccumulator, aggregate, evaluate


def test_evaluate_hand_computed():
    pred = np.array([[1.0, 2.0, 3.0, 10.0]])
    gt = np.array([[1.5, 2.0, 7.0, 4.0]])
    m = evaluate(pred, gt)  # errors 0.5, 0, 4, 6
    assert m["n"] == 4
    assert m["epe"] == pytest.approx(10.5 / 4)
    assert m["bad0.5"] == 50.0  # 0.5 is not > 0.5
    assert m["bad1"] == m["bad2"] == m["bad3"] == 50.0
    assert m["bad4"] == m["bad5"] == 25.0
    assert m["bad7"] == 0.0
    assert m["rms"] == pytest.approx(math.sqrt((0.25 + 16 + 36) / 4))
    # sorted errors [0, 0.5, 4, 6]; linear percentile at position q/100 * 3
    assert m["a50"] == pytest.approx(2.25)
    assert m["a90"] == pytest.approx(5.4)
    assert m["a95"] == pytest.approx(5.7)
    assert m["a99"] == pytest.approx(5.94)
    assert m["d1"] == 50.0  # 4 > 0.35 and 6 > 0.2
    assert set(m) == set(METRIC_KEYS) | {"n"}


def test_d1_needs_both_3px_and_5_percent():
    m = evaluate(np.array([96.0, 14.0]), np.array([100.0, 10.0]))  # errors 4, 4
    assert m["bad3"] == 100.0
    assert m["d1"] == 50.0  # 4 < 5 % of 100


def test_evaluation_mask_excludes_invalid_gt_and_masked_pixels():
    gt = np.array([2.0, np.inf, 0.0, -1.0, np.nan, 3.0, 5.0])
    pred = np.array([3.0, 100.0, 100.0, 100.0, 100.0, 3.0, 100.0])
    valid = np.array([1, 1, 1, 1, 1, 1, 0], bool)
    m = evaluate(pred, gt, valid)
    assert m["n"] == 2
    assert m["epe"] == pytest.approx(0.5)


def test_non_finite_predictions_count_as_zero():
    m = evaluate(np.array([np.nan, np.inf]), np.array([2.0, 4.0]))
    assert m["epe"] == pytest.approx(3.0)


def test_empty_evaluation_is_nan():
    m = evaluate(np.zeros((2, 2)), np.zeros((2, 2)))
    assert m["n"] == 0 and all(math.isnan(m[k]) for k in METRIC_KEYS)


def test_shape_mismatch_raises_runtime_error():
    with pytest.raises(ShapeError, match=r"\(2, 3\).*\(3, 2\)"):
        evaluate(np.zeros((2, 3)), np.ones((3, 2)))
    with pytest.raises(RuntimeError):
        evaluate(np.zeros((2, 3)), np.ones((2, 3)), valid=np.ones((3, 2), bool))


def test_aggregate_mean_and_pooled_accumulator():
    a = (np.array([[1.0]]), np.array([[2.0]]))  # error 1
    b = (np.array([[0.0, 0.0]]), np.array([[3.0, 1.0]]))  # errors 3, 1
    empty = (np.zeros((1, 1)), np.zeros((1, 1)))  # nothing evaluated: skipped by the mean
    per_image = [evaluate(*x) for x in (a, b, empty)]
    mean = aggregate(per_image)
    assert mean["epe"] == pytest.approx((1 + 2) / 2)
    assert mean["a50"] == pytest.approx((1 + 2) / 2)
    assert mean["bad2"] == pytest.approx((0 + 50) / 2)
    assert mean["n"] == 3 and mean["images"] == 2

    acc = MetricAccumulator()
    for pred, gt in (a, b, empty):
        assert acc.update(pred, gt) == evaluate(pred, gt)
    pooled = acc.compute()
    assert pooled["epe"] == pytest.approx(5 / 3)
    assert pooled["a50"] == pytest.approx(1.0)  # median of [1, 3, 1]
    assert pooled["bad2"] == pytest.approx(100 / 3)
    assert pooled["rms"] == pytest.approx(math.sqrt(11 / 3))
    assert pooled["n"] == 3


def test_accumulator_without_quantiles_and_reset():
    acc = MetricAccumulator(quantiles=False)
    acc.update(np.array([1.0, 2.0]), np.array([2.0, 2.0]))
    result = acc.compute()
    assert result["epe"] == pytest.approx(0.5) and math.isnan(result["a90"])
    acc.reset()
    assert acc.compute()["n"] == 0


def test_aggregate_rejects_unknown_mode():
    with pytest.raises(ValueError, match="MetricAccumulator"):
        aggregate([], mode="pooled")
    assert aggregate([])["images"] == 0


# ------------------------------------------------------------------------------ evaluation


def _pairs():
    gt = np.array([[2.0, 4.0, 0.0, 8.0]], np.float32)
    valid = np.array([[True, True, True, True]])
    image = np.zeros((1, 4, 3), np.uint8)
    return [{"left": image, "right": image, "disparity": gt, "valid": valid, "meta": {"left": "a.png"}},
            {"left": image, "right": image, "disparity": gt * 2, "valid": valid}]


def test_evaluate_method_full_versus_covered():
    constant = lambda left, right: (np.full((1, 4), 3.0), np.array([[True, True, True, False]]))  # noqa: E731
    full = evaluate_method(_pairs(), constant, coverage="full")
    covered = evaluate_method(_pairs(), constant, coverage="covered")
    # pair 1: gt 2, 4, (0 unevaluated), 8; full errors 1, 1, 8 (hole = prediction 0); covered 1, 1
    # pair 2: gt 4, 8, 16; full errors 1, 5, 16; covered 1, 5
    assert [r["epe"] for r in full["per_image"]] == pytest.approx([10 / 3, 22 / 3])
    assert [r["epe"] for r in covered["per_image"]] == pytest.approx([1.0, 3.0])
    assert full["mean"]["epe"] == pytest.approx(16 / 3)
    assert full["pooled"]["epe"] == pytest.approx(32 / 6)
    assert covered["pooled"]["epe"] == pytest.approx(8 / 4)
    assert full["coverage"] == covered["coverage"] == pytest.approx(100 * 4 / 6)
    assert full["per_image"][0]["name"] == "a.png" and full["per_image"][1]["name"] == 1


def test_evaluate_method_plain_array_predictor_and_shape_check():
    exact = evaluate_method(_pairs(), lambda left, right: np.array([[2.0, 4.0, 9.0, 8.0]]))
    assert exact["per_image"][0]["epe"] == 0.0 and exact["coverage"] == 100.0
    with pytest.raises(ShapeError):
        evaluate_method(_pairs(), lambda left, right: np.zeros((2, 2)))


def test_mipnet_rows_score_the_dense_output_and_its_confident_pixels():
    import mipnet

    rng = np.random.default_rng(0)
    scene = rng.uniform(0, 255, (48, 110, 3))
    truth = np.full((48, 96), 6.0, np.float32)
    pair = {"left": scene[:, :96], "right": scene[:, 6:102], "disparity": truth, "valid": np.ones((48, 96), bool)}
    guess = truth.copy()
    guess[:, 60:] += 5.0  # wrong by 5 px on the right part: not backed by the images there

    dense, confident = mipnet_rows([pair], lambda left, right: guess, aggregation="pooled", min_confidence=0.5)
    kept = mipnet.match_confidence(pair["left"], pair["right"], guess) >= 0.5
    assert dense["method"] == "MIPNet" and dense["coverage"] == 100.0
    assert dense["epe"] == pytest.approx(5.0 * 36 / 96)
    assert confident["method"] == "MIPNet (confidence >= 0.5)"
    assert confident["coverage"] == pytest.approx(100 * kept.mean())
    assert confident["epe"] == pytest.approx(np.abs(guess - truth)[kept].mean()) and confident["epe"] < 0.2 * dense["epe"]
    assert mipnet_rows([pair], lambda left, right: guess)[0]["epe"] == pytest.approx(dense["epe"])


def test_format_table():
    result = evaluate_method(_pairs(), lambda left, right: np.array([[2.0, 4.0, 9.0, 8.0]]))
    rows = [result_row("exact", result), {"method": "other", "epe": 12.345, "bad1": float("nan")}]
    table = format_table(rows)
    lines = table.splitlines()
    assert len(lines) == 4
    assert lines[0].startswith("| method") and "epe" in lines[0] and "coverage" in lines[0]
    assert "| exact" in lines[2] and "2.333" in lines[2]  # mean of per-image EPE 0 and 14/3
    assert "12.35" in lines[3] and "-" in lines[3]
    assert len({len(line) for line in lines}) == 1  # aligned
    assert format_table(rows, columns=["method", "epe"]).splitlines()[0].split() == ["|", "method", "|", "epe", "|"]
