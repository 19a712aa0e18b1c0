"""Generated moving-camera sequences (``mipnet.data.make_sequence``): deterministic, exact correspondences, a
smooth path, the cut, water, the ``sequence`` dataset, and the temporal metrics they feed."""

import math

import numpy as np
import pytest

from mipnet.data import make_scene
from mipnet.data.registry import open_dataset, parse_spec
from mipnet.data import scenes
from mipnet.data.sequences import MAX_OFFSET, TRAVEL, SequenceSet, _Rig, make_sequence
from mipnet.errors import ArgumentError, ShapeError
from mipnet.stereo.temporal import flicker, score_sequence, summarise_frames, warp_previous

SIZE = (48, 64)


@pytest.fixture(scope="module")
def sequence():
    return make_sequence(7, frames=6, size=SIZE)


def test_a_sequence_is_a_deterministic_function_of_its_seed(sequence):
    again = make_sequence(7, frames=6, size=SIZE)
    for a, b in zip(sequence, again):
        for key in ("left", "right", "disparity", "valid", "previous_x"):
            np.testing.assert_array_equal(a[key], b[key])
    other = make_sequence(8, frames=6, size=SIZE)
    assert not np.array_equal(sequence[0]["disparity"], other[0]["disparity"])
    assert [f["meta"]["frame"] for f in sequence] == list(range(6))
    for frame in sequence:
        assert frame["left"].shape == SIZE + (3,) and frame["left"].dtype == np.uint8
        assert frame["disparity"].dtype == np.float32 and frame["valid"].dtype == bool
        assert 0.5 < frame["valid"].mean() <= 1.0


def test_the_rig_moves_smoothly_along_its_baseline(sequence):
    offsets = np.array([f["offset"] for f in sequence])
    travel = abs(offsets[-1] - offsets[0])
    assert TRAVEL[0] - 1e-12 <= travel <= TRAVEL[1] + 1e-12
    assert offsets.min() >= 0.0 and offsets.max() <= MAX_OFFSET
    steps = np.diff(offsets)
    assert np.all(steps * np.sign(offsets[-1] - offsets[0]) >= 0)  # one direction
    # the ease (1 - cos(pi t / (N - 1))) / 2: speed at most pi / 2 times the mean, acceleration at most pi^2 / 2
    # times travel / (N - 1)^2
    n = len(offsets) - 1
    assert np.abs(steps).max() <= math.pi / 2 * travel / n + 1e-12
    assert np.abs(np.diff(steps)).max() <= math.pi ** 2 / 2 * travel / n ** 2 + 1e-12
    # parallax: the nearest points move the most, each by (s_t - s_{t-1}) d pixels
    for frame, step in zip(sequence[1:], steps):
        known = np.isfinite(frame["previous_x"])
        shift = frame["previous_x"][known] - np.nonzero(known)[1]
        np.testing.assert_allclose(shift, step * frame["disparity"][known], atol=1e-3)


def test_correspondences_are_exact_where_the_point_is_seen_in_both_frames(sequence):
    assert np.isnan(sequence[0]["previous_x"]).all()
    for previous, frame in zip(sequence, sequence[1:]):
        known = np.isfinite(frame["previous_x"])
        assert known.mean() > 0.8
        # the same 3-D point: the same disparity in the previous frame (up to interpolation at depth edges)
        moved = np.abs(warp_previous(previous["disparity"], frame["previous_x"])[known] - frame["disparity"][known])
        assert np.median(moved) < 1e-3
        assert flicker(frame["disparity"], previous["disparity"], frame["previous_x"]) < 0.25  # edges only
        # and the same colour, up to the sensor noise and the rounding to a pixel: far closer than other pixels'
        rows, cols = np.nonzero(known)
        source = np.rint(frame["previous_x"][known]).astype(int)
        followed = np.abs(previous["left"][rows, source].astype(float) - frame["left"][rows, cols]).mean()
        shuffled = np.random.default_rng(0).permutation(source.size)
        other = np.abs(previous["left"][rows, source][shuffled].astype(float) - frame["left"][rows, cols]).mean()
        assert followed < 12 and followed < other / 3


def test_the_rig_at_offset_0_is_the_scene_generator_s_reference_camera():
    scene, _ = scenes._compose(3, *SIZE, SIZE[1] / 4)
    rig = _Rig(scene)
    _, disparity, _ = rig.view(0.0)
    np.testing.assert_array_equal(disparity.astype(np.float32), make_scene(*SIZE, 3)["disparity"])
    # the renderer of the scaled fields (offset > 0) agrees with the reference camera as the offset goes to 0
    _, nearly, _ = rig.view(1e-9)
    np.testing.assert_allclose(nearly, disparity, atol=1e-4)


def test_a_cut_starts_another_scene_without_correspondences():
    frames = make_sequence(11, frames=5, size=SIZE, cut_at=3)
    before = make_sequence(11, frames=3, size=SIZE)
    for a, b in zip(frames[:3], before):  # the frames before the cut are the uncut sequence of that length
        np.testing.assert_array_equal(a["left"], b["left"])
        np.testing.assert_array_equal(a["disparity"], b["disparity"])
    assert [f["scene"] for f in frames] == [0, 0, 0, 1, 1]
    assert np.isnan(frames[3]["previous_x"]).all() and np.isfinite(frames[4]["previous_x"]).any()
    assert np.abs(frames[3]["disparity"] - frames[2]["disparity"]).mean() > 1.0
    assert frames[3]["meta"]["scene_seed"] != frames[2]["meta"]["scene_seed"]


def test_water_degrades_every_frame_and_keeps_the_geometry():
    dry = make_sequence(5, frames=2, size=SIZE)
    wet = make_sequence(5, frames=2, size=SIZE, water="turbid")
    for a, b in zip(dry, wet):
        np.testing.assert_array_equal(a["disparity"], b["disparity"])
        np.testing.assert_array_equal(a["previous_x"], b["previous_x"])
        assert not np.array_equal(a["left"], b["left"])
        assert b["meta"]["underwater"] == "turbid"
    with pytest.raises(ArgumentError, match="underwater"):
        make_sequence(5, frames=2, size=SIZE, water="soup")


@pytest.mark.parametrize("kwargs", [dict(frames=0), dict(frames=3, cut_at=0), dict(frames=3, cut_at=3),
                                    dict(size=(0, 64)), dict(size=48)])
def test_bad_arguments_are_one_clear_error(kwargs):
    with pytest.raises(ArgumentError, match="make_sequence"):
        make_sequence(1, **kwargs)


def test_the_sequence_dataset_is_registered_for_evaluation_only():
    dataset = open_dataset("sequence", size=SIZE, seed=1_000_000, count=2)
    assert isinstance(dataset, SequenceSet) and len(dataset) == 2
    item = SequenceSet(1, *SIZE, frames=2)[0]
    assert len(item["frames"]) == 2 and item["meta"]["seed"] == 1_000_000
    with pytest.raises(ArgumentError, match="unknown dataset 'sequence'"):
        parse_spec("sequence")


def test_scores_and_flicker_of_a_perfect_and_a_noisy_predictor(sequence):
    truth = iter(f["disparity"] for f in sequence)
    perfect = summarise_frames([score_sequence(sequence, lambda l, r: next(truth))])
    assert perfect["all"]["epe"] == 0.0 and perfect["all"]["bad3"] == 0.0
    assert perfect["all"]["flicker"] == pytest.approx(perfect["all"]["flicker_gt"])
    assert math.isnan(perfect["frames"][0]["flicker"]) and perfect["all"]["frames"] == len(sequence)
    # a predictor off by t px at frame t: EPE 1 on average, and each frame's flicker within the ground truth's of 1
    frames = iter(enumerate(f["disparity"] for f in sequence))
    drifting = score_sequence(sequence, lambda l, r: (lambda t, d: d + t)(*next(frames)))
    assert [r["epe"] for r in drifting] == pytest.approx(list(range(len(sequence))), abs=1e-4)
    for record in drifting[1:]:
        assert abs(record["flicker"] - 1.0) <= record["flicker_gt"] + 1e-6
    with pytest.raises(ShapeError, match="warp_previous"):
        warp_previous(np.zeros((4, 5)), np.zeros((4, 6)))
