"""Training augmentations of architecture.md §3.3 (mipnet.training.augment): each test checks what a step must
preserve — stereo geometry, the disparity scale, the valid mask, the left image, value ranges —
and that every draw comes from the generator it is given."""

import dataclasses

import numpy as np
import pytest
from helpers import require, sample_right
from hypothesis import given, settings
from hypothesis import strategies as st
from mipnet.data import make_pair
from mipnet.utils.data.dataloader import DataLoader
from mipnet.errors import ArgumentError, DTypeError, ShapeError
from mipnet.training.augment import (
    AugmentParams,
    NoiseParams,
    SparseStereoAugmentor,
    StereoAugmentor,
    VeilParams,
    make_augmentor,
)

#: every step off except the crop (and what a test switches back on)
OFF = dict(photometric=False, eraser_prob=0.0, patch_prob=0.0, spatial=False, yjitter=0)


def require_cv2():
    """cv2 is a test dependency only (see helpers.require)."""
    return require("cv2")


@pytest.fixture(scope="module")
def pair():
    return make_pair(120, 180, seed=11)


def _rng(seed):
    return np.random.default_rng(seed)


def _copy(sample):
    return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in sample.items()}


def _erode(mask, radius=2):
    """Pixels whose (2r+1)^2 neighbourhood is all True (outside the image counts as False)."""
    padded = np.pad(mask, radius, constant_values=False)
    out = np.ones_like(mask)
    height, width = mask.shape
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            out &= padded[dy:dy + height, dx:dx + width]
    return out


def _window(origin, crop, delta=0):
    """Index of the crop at ``origin`` = (y0, x0), its rows shifted by ``delta``."""
    (y0, x0), (ch, cw) = origin, crop
    return np.s_[y0 + delta:y0 + delta + ch, x0:x0 + cw]


def _check_contract(out, crop):
    ch, cw = crop
    assert out["left"].shape == out["right"].shape == (ch, cw, 3)
    assert out["disparity"].shape == out["valid"].shape == (ch, cw)
    assert out["left"].dtype == out["right"].dtype == np.uint8
    assert out["disparity"].dtype == np.float32 and out["valid"].dtype == bool
    for key in ("left", "right", "disparity", "valid"):
        assert out[key].flags.c_contiguous, key
    assert np.isfinite(out["disparity"]).all()


# ------------------------------------------------------------------------------ determinism, contract


@pytest.mark.parametrize("cls", [StereoAugmentor, SparseStereoAugmentor])
def test_same_seed_same_sample_other_seed_other_sample(pair, cls):
    aug = cls((64, 96))
    first, again, other = aug(pair, _rng(5)), aug(pair, _rng(5)), aug(pair, _rng(6))
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(first[key], again[key], err_msg=key)
    assert aug.draw((120, 180), _rng(5)) == aug.draw((120, 180), _rng(5))
    assert not np.array_equal(first["left"], other["left"])


def test_dataloader_batches_are_reproducible():
    from mipnet.data import SyntheticStereo

    loader = DataLoader(SyntheticStereo(4, 72, 100, seed=3), batch_size=2, shuffle=True, seed=9,
                        transform=StereoAugmentor((40, 64)))
    loader.set_epoch(2)
    first = list(loader)
    loader.set_epoch(2)
    second = list(loader)
    assert len(first) == 2
    for a, b in zip(first, second):
        assert a["left"].shape == (2, 40, 64, 3)
        for key in ("left", "right", "disparity", "valid"):
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize("cls", [StereoAugmentor, SparseStereoAugmentor])
def test_contract_passthrough_and_inputs_untouched(pair, cls):
    sample = dict(_copy(pair), meta={"index": 3}, name="pair")
    before = _copy(sample)
    for seed in range(6):
        out = cls((64, 96), eraser_prob=1.0, patch_prob=1.0)(sample, _rng(seed))
        _check_contract(out, (64, 96))
        assert out["meta"] is sample["meta"] and out["name"] == "pair"
        if cls is StereoAugmentor:
            assert (np.abs(out["disparity"][out["valid"]]) < 512).all()
        else:
            assert (out["disparity"][~out["valid"]] == 0).all()
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(sample[key], before[key], err_msg=key)


def test_crop_only_is_a_plain_crop(pair):
    aug = make_augmentor((64, 96), augment=False)
    for seed in range(5):
        params = aug.draw((120, 180), _rng(seed))
        out = aug.apply(pair, params)
        (y0, x0), crop = params.origin, _window(params.origin, (64, 96))
        assert params.scale == (1.0, 1.0) and params.delta == 0 and params.color == () and params.erase == ()
        assert 0 <= y0 <= 120 - 64 and 0 <= x0 <= 180 - 96
        for key in ("left", "right", "disparity", "valid"):
            np.testing.assert_array_equal(out[key], pair[key][crop], err_msg=key)


def test_make_augmentor_picks_class_and_overrides():
    assert type(make_augmentor((32, 48))) is StereoAugmentor
    sparse = make_augmentor((32, 48), sparse=True, eraser_prob=0.0)
    assert type(sparse) is SparseStereoAugmentor and sparse.eraser_prob == 0.0
    off = make_augmentor((32, 48), sparse=True, augment=False, photometric=True)
    assert off.photometric and not off.spatial and off.patch_prob == 0.0
    dense = StereoAugmentor((32, 48))
    assert dense.brightness == (0.6, 1.4) and dense.saturation == (0.0, 1.4)
    assert dense.hue == pytest.approx((-0.5 / 3.14, 0.5 / 3.14)) and dense.max_disparity == 512.0
    assert sparse.brightness == pytest.approx((0.7, 1.3)) and sparse.hue == pytest.approx((-0.3 / 3.14, 0.3 / 3.14))


# ------------------------------------------------------------------------------ photometric


def test_photometric_only_leaves_disparity_and_valid_unchanged(pair):
    aug = StereoAugmentor((120, 180), **{**OFF, "photometric": True}, gamma=(0.7, 1.5), gain=(0.9, 1.1))
    changed = 0
    for seed in range(8):
        out = aug(pair, _rng(seed))
        np.testing.assert_array_equal(out["disparity"], pair["disparity"])
        np.testing.assert_array_equal(out["valid"], pair["valid"])
        changed += not np.array_equal(out["left"], pair["left"])
    assert changed == 8


def test_symmetric_jitter_treats_both_views_alike_asymmetric_does_not():
    left = make_pair(80, 120, seed=2)["left"]
    sample = {"left": left, "right": left.copy(), "disparity": np.zeros((80, 120), np.float32),
              "valid": np.ones((80, 120), bool)}
    symmetric = StereoAugmentor((80, 120), **{**OFF, "photometric": True}, asymmetric_prob=0.0)
    asymmetric = StereoAugmentor((80, 120), **{**OFF, "photometric": True}, asymmetric_prob=1.0)
    differ = 0
    for seed in range(10):
        out = symmetric(sample, _rng(seed))
        np.testing.assert_array_equal(out["left"], out["right"])
        assert len(symmetric.draw((80, 120), _rng(seed)).color) == 1
        params = asymmetric.draw((80, 120), _rng(seed))
        assert len(params.color) == 2 and params.color[0] != params.color[1]
        out = asymmetric.apply(sample, params)
        differ += np.abs(out["left"].astype(int) - out["right"].astype(int)).mean() > 1.0
    assert differ >= 9


def test_asymmetric_probability_is_about_the_spec_value():
    aug = StereoAugmentor((32, 48))
    share = np.mean([len(aug.draw((64, 96), _rng(seed)).color) == 2 for seed in range(400)])
    assert 0.14 < share < 0.26


def test_colour_and_occluders_on_the_window_equal_the_whole_image(pair):
    """The pipeline colours only the source window the crop reads, and the patch source separately;
    without contrast (whose pivot is the window's mean grey) that must be the whole-image result."""
    opts = dict(OFF, photometric=True, contrast=0.0, patch_prob=1.0, asymmetric_prob=0.5)
    window, whole = StereoAugmentor((56, 80), **opts), StereoAugmentor((120, 180), **opts)
    for seed in range(12):
        params = window.draw((120, 180), _rng(seed))
        crop = _window(params.origin, (56, 80))
        full = whole.apply(pair, dataclasses.replace(params, origin=(0, 0)))
        out = window.apply(pair, params)
        np.testing.assert_array_equal(out["left"], full["left"][crop])
        np.testing.assert_array_equal(out["right"], full["right"][crop])


# ------------------------------------------------------------------------------ occluders


def test_eraser_fills_rectangles_of_the_right_image_only(pair):
    aug = StereoAugmentor((120, 180), **{**OFF, "eraser_prob": 1.0})
    for seed in range(8):
        params = aug.draw((120, 180), _rng(seed))
        out = aug.apply(pair, params)
        for key in ("left", "disparity", "valid"):
            np.testing.assert_array_equal(out[key], pair[key], err_msg=key)
        assert 1 <= len(params.erase) <= 2
        inside = np.zeros((120, 180), bool)
        for y, x, h, w in params.erase:
            inside[y:y + h, x:x + w] = True
        fill = np.rint(pair["right"].reshape(-1, 3).mean(axis=0)).astype(np.uint8)
        assert (out["right"][inside] == fill).all()
        np.testing.assert_array_equal(out["right"][~inside], pair["right"][~inside])


def test_eraser_sides_follow_the_spec_and_shrink_for_small_images():
    aug = StereoAugmentor((32, 48), eraser_prob=1.0)
    sides = [s for seed in range(200) for r in aug.draw((400, 600), _rng(seed)).erase for s in r[2:]]
    assert min(sides) == 50 and max(sides) == 99
    counts = {len(aug.draw((400, 600), _rng(seed)).erase) for seed in range(50)}
    assert counts == {1, 2}
    small = [s for seed in range(200) for r in aug.draw((64, 96), _rng(seed)).erase for s in r[2:]]
    # sides scaled by min(H, W) / 384 = 1/6: U{8..16}
    assert min(small) == 8 and max(small) == 16


def test_patch_copies_the_right_image_onto_itself(pair):
    aug = StereoAugmentor((120, 180), **{**OFF, "patch_prob": 1.0})
    for seed in range(8):
        params = aug.draw((120, 180), _rng(seed))
        out = aug.apply(pair, params)
        for key in ("left", "disparity", "valid"):
            np.testing.assert_array_equal(out[key], pair[key], err_msg=key)
        sy, sx, dy, dx, h, w = params.patch
        assert 0 <= dy and dy + h <= 120 and 0 <= dx and dx + w <= 180
        np.testing.assert_array_equal(out["right"][dy:dy + h, dx:dx + w], pair["right"][sy:sy + h, sx:sx + w])
        outside = np.ones((120, 180), bool)
        outside[dy:dy + h, dx:dx + w] = False
        np.testing.assert_array_equal(out["right"][outside], pair["right"][outside])


def test_eraser_then_patch_on_a_window_matches_a_whole_image_reference(pair):
    """Eraser, then patch, computed on the crop window (the fill is the window's mean colour)."""
    aug = StereoAugmentor((64, 100), **{**OFF, "eraser_prob": 1.0, "patch_prob": 1.0})
    for seed in range(20):
        params = aug.draw((120, 180), _rng(seed))
        crop = _window(params.origin, (64, 100))
        reference = pair["right"].copy()
        fill = np.rint(reference[crop].reshape(-1, 3).mean(axis=0)).astype(np.uint8)
        for y, x, h, w in params.erase:
            reference[y:y + h, x:x + w] = fill
        sy, sx, dy, dx, h, w = params.patch
        reference[dy:dy + h, dx:dx + w] = reference[sy:sy + h, sx:sx + w].copy()
        out = aug.apply(pair, params)
        np.testing.assert_array_equal(out["right"], reference[crop])
        np.testing.assert_array_equal(out["left"], pair["left"][crop])


# ------------------------------------------------------------------------------ spatial


def test_bilinear_resize_matches_cv2_inter_linear(pair):
    cv2 = require_cv2()
    aug = StereoAugmentor((56, 88), **{**OFF, "spatial": True, "yjitter": 2}, scale_range=(-0.6, 0.9))
    disparity = pair["disparity"] + np.random.default_rng(0).normal(0, 3, (120, 180)).astype(np.float32)
    sample = dict(pair, disparity=disparity, valid=np.ones((120, 180), bool))
    scales = []
    for seed in range(25):
        params = aug.draw((120, 180), _rng(seed))
        (s_y, s_x), dy = params.scale, params.delta
        out = aug.apply(sample, params)
        resized = {k: cv2.resize(sample[k], None, fx=s_x, fy=s_y, interpolation=cv2.INTER_LINEAR)
                   for k in ("left", "right", "disparity")}
        assert resized["left"].shape[:2] == params.size
        crop, crop_right = _window(params.origin, (56, 88)), _window(params.origin, (56, 88), dy)
        # cv2 computes uint8 in 11-bit fixed point: at most one level apart
        assert np.abs(out["left"].astype(int) - resized["left"][crop]).max() <= 1
        assert np.abs(out["right"].astype(int) - resized["right"][crop_right]).max() <= 1
        np.testing.assert_allclose(out["disparity"], resized["disparity"][crop] * np.float32(s_x),
                                   rtol=1e-5, atol=1e-4)
        scales += [s_y, s_x]
    assert min(scales) < 0.8 and max(scales) > 1.3


def test_warp_consistency_after_scale_and_stretch():
    """After resize + stretch the right image sampled at x - d must still match the left image;
    the unscaled disparity and the one scaled by s_y (not s_x) must not."""
    pair = make_pair(160, 240, seed=7)
    aug = StereoAugmentor((96, 160), **{**OFF, "spatial": True}, stretch_prob=1.0)
    checked = 0
    for seed in range(10):
        params = aug.draw((160, 240), _rng(seed))
        s_y, s_x = params.scale
        out = aug.apply(pair, params)
        warped, inside = sample_right(out["right"], out["disparity"])
        mask = _erode(out["valid"]) & inside
        assert mask.mean() > 0.5
        error = np.abs(warped - out["left"])[mask].mean()
        assert error < 1.0, (seed, params.scale, error)
        for wrong_factor in (1.0 / s_x, s_y / s_x):
            if abs(wrong_factor - 1.0) > 0.1:
                wrong, inside_wrong = sample_right(out["right"], out["disparity"] * wrong_factor)
                assert np.abs(wrong - out["left"])[mask & inside_wrong].mean() > 2 * error, (seed, wrong_factor)
                checked += 1
    assert checked >= 5


def test_constant_disparity_is_multiplied_by_sx():
    texture = make_pair(100, 170, seed=4)["left"]
    shift = 6
    # right(x) = left(x + 6): a constant disparity of 6 px everywhere
    sample = {"left": texture[:, :160], "right": texture[:, shift:shift + 160],
              "disparity": np.full((100, 160), shift, np.float32), "valid": np.ones((100, 160), bool)}
    aug = StereoAugmentor((64, 96), **{**OFF, "spatial": True}, stretch_prob=1.0)
    for seed in range(10):
        params = aug.draw((100, 160), _rng(seed))
        out = aug.apply(sample, params)
        np.testing.assert_allclose(out["disparity"], shift * params.scale[1], rtol=1e-6)
        assert out["valid"].all()


def test_stretch_and_scale_draws_follow_the_spec():
    aug = StereoAugmentor((32, 48))
    draws = [aug.draw((400, 600), _rng(seed)).scale for seed in range(400)]
    log_y, log_x = np.log2(np.array(draws)).T
    # s = 2**U(-0.2, 0.4), each axis times 2**U(-0.2, 0.2): log2 within [-0.4, 0.6]
    assert log_x.min() >= -0.4 - 1e-9 and log_x.max() <= 0.6 + 1e-9 and log_y.min() >= -0.4 - 1e-9
    stretched = np.mean(np.abs(log_x - log_y) > 1e-12)
    assert 0.72 < stretched < 0.88
    plain = StereoAugmentor((32, 48), stretch_prob=0.0)
    assert all(p.scale[0] == p.scale[1] for p in (plain.draw((400, 600), _rng(s)) for s in range(50)))


def test_scale_is_clamped_so_the_crop_fits_with_margin():
    aug = StereoAugmentor((100, 150), scale_range=(-1.0, -1.0), stretch_prob=0.0)
    params = aug.draw((200, 300), _rng(0))
    # 2**-1 = 0.5 would give 100x150; the clamp max((100+8)/200, (150+8)/300) = 0.54
    assert params.scale == (0.54, 0.54) and params.size == (108, 162)


def test_valid_mask_never_grows_into_invalid_sources():
    """A resized pixel is valid iff every source pixel it interpolates from is: the bilinear resize
    of the 0/1 mask is 1 there. A nearest-resized mask would be wrong at the edges of holes."""
    cv2 = require_cv2()
    rng = np.random.default_rng(1)
    valid = rng.random((90, 130)) > 0.05
    valid[30:50, 40:70] = False
    sample = {"left": np.zeros((90, 130, 3), np.uint8), "right": np.zeros((90, 130, 3), np.uint8),
              "disparity": np.ones((90, 130), np.float32), "valid": valid}
    aug = StereoAugmentor((56, 80), **{**OFF, "spatial": True}, stretch_prob=1.0)
    nearest_grows = 0
    for seed in range(10):
        params = aug.draw((90, 130), _rng(seed))
        s_y, s_x = params.scale
        out = aug.apply(sample, params)
        crop = _window(params.origin, (56, 80))
        blended = cv2.resize(valid.astype(np.float32), None, fx=s_x, fy=s_y, interpolation=cv2.INTER_LINEAR)[crop]
        np.testing.assert_array_equal(out["valid"], blended > 1 - 1e-6)
        nearest = cv2.resize(valid.astype(np.uint8), None, fx=s_x, fy=s_y, interpolation=cv2.INTER_NEAREST)[crop] > 0
        nearest_grows += int((nearest & (blended < 1 - 1e-6)).any())
    assert out["valid"].mean() < valid.mean()
    assert nearest_grows == 10


def test_invalid_and_large_disparity_become_invalid(pair):
    disparity = pair["disparity"].copy()
    disparity[:10] = np.inf
    disparity[10:20] = np.nan
    disparity[:, :30] = 600.0
    sample = dict(pair, disparity=disparity, valid=np.ones((120, 180), bool))
    out = StereoAugmentor((120, 180), **OFF)(sample, _rng(0))
    assert not out["valid"][:20].any() and not out["valid"][:, :30].any() and out["valid"][20:, 30:].all()
    assert np.isfinite(out["disparity"]).all()
    kept = StereoAugmentor((120, 180), **OFF, max_disparity=None)(sample, _rng(0))
    assert kept["valid"][20:, :30].all()


# ------------------------------------------------------------------------------ y-jitter


def test_yjitter_moves_only_the_right_crop_by_at_most_two_rows(pair):
    aug = StereoAugmentor((80, 120), **{**OFF, "yjitter": 2})
    deltas = set()
    for seed in range(40):
        params = aug.draw((120, 180), _rng(seed))
        (y0, x0), dy = params.origin, params.delta
        out = aug.apply(pair, params)
        assert abs(dy) <= 2 and params.scale == (1.0, 1.0)
        # spec: y0 ~ U{2, H' - crop_h - 3}, x0 ~ U{2, W' - crop_w - 3}
        assert 2 <= y0 <= 120 - 80 - 3 and 2 <= x0 <= 180 - 120 - 3
        for key in ("left", "disparity", "valid"):
            np.testing.assert_array_equal(out[key], pair[key][y0:y0 + 80, x0:x0 + 120], err_msg=key)
        np.testing.assert_array_equal(out["right"], pair["right"][y0 + dy:y0 + dy + 80, x0:x0 + 120])
        deltas.add(dy)
    assert deltas == {-2, -1, 0, 1, 2}


@pytest.mark.parametrize("field, before", [("veil", {}), ("noise", {"veil_prob": 0.5})])
def test_optional_step_is_drawn_last_and_changes_no_other_draw(field, before):
    """veil_prob > 0 (noise_prob > 0) adds its draw after every other (the veil's too), so runs without it see
    the augmentation they saw before it existed."""
    plain, extra = StereoAugmentor((80, 120), **before), StereoAugmentor((80, 120), **before, **{f"{field}_prob": 1.0})
    for seed in range(10):
        without, with_step = plain.draw((120, 180), _rng(seed)), extra.draw((120, 180), _rng(seed))
        assert getattr(without, field) is None and getattr(with_step, field) is not None
        assert dataclasses.replace(with_step, **{field: None}) == without


def test_veil_draws_follow_the_docstring():
    aug = StereoAugmentor((80, 120), veil_prob=0.5)
    veils = [aug.draw((200, 300), _rng(seed)).veil for seed in range(400)]
    drawn = [v for v in veils if v is not None]
    assert 0.4 < len(drawn) / len(veils) < 0.6
    for v in drawn:
        assert -0.3 * 200 <= v.top <= 0.9 * 200 and 0.15 * 200 <= v.bottom - v.top <= 0.7 * 200
        assert 0.05 * 200 <= v.soft <= 0.3 * 200 and 0.5 <= v.strength <= 0.92
        assert all(0.3 * 255 <= c <= 1.0 * 255 for c in v.colour)


def test_veil_alpha_is_strength_in_the_band_and_zero_beyond_its_soft_edges():
    veil = VeilParams(top=20.0, bottom=40.0, soft=10.0, strength=0.8, colour=(200.0, 200.0, 200.0))
    rows = np.arange(0, 60, dtype=np.float64)
    alpha = veil.alpha(rows)
    np.testing.assert_allclose(alpha[20:41], 0.8)
    np.testing.assert_allclose(alpha[:11], 0.0, atol=1e-12)
    np.testing.assert_allclose(alpha[50:], 0.0, atol=1e-12)
    assert np.all(np.diff(alpha[10:21]) > 0) and np.all(np.diff(alpha[40:51]) < 0)
    image = np.full((60, 4, 3), 100, np.uint8)
    out = veil.apply(image, first_row=0)
    # inside the band: 0.2 * 100 + 0.8 * 200 = 180; far outside: unchanged
    assert (out[25] == 180).all() and (out[0] == 100).all() and (out[59] == 100).all()


def test_veil_keeps_the_pair_consistent_for_any_depth():
    """The veil depends on the row only, so right(x - d) = left(x) still holds where it did,
    even with y-jitter (both crops are veiled at their source rows)."""
    texture = make_pair(100, 170, seed=4)["left"]
    shift = 6
    # right(x) = left(x + 6): a constant disparity of 6 px everywhere
    sample = {"left": texture[:, :160], "right": texture[:, shift:shift + 160],
              "disparity": np.full((100, 160), shift, np.float32), "valid": np.ones((100, 160), bool)}
    aug = StereoAugmentor((64, 96), **{**OFF, "yjitter": 2}, veil_prob=1.0)
    changed = 0
    for seed in range(10):
        params = aug.draw((100, 160), _rng(seed))
        out = aug.apply(sample, params)
        (y0, x0), dy = params.origin, params.delta
        rows = np.arange(y0 + dy, y0 + dy + 64)
        expected_right = params.veil.apply(texture[rows, x0 + shift:x0 + shift + 96], y0 + dy)
        np.testing.assert_array_equal(out["right"], expected_right)
        np.testing.assert_array_equal(out["left"], params.veil.apply(texture[y0:y0 + 64, x0:x0 + 96], y0))
        # the left crop's row r and the right crop's row r - dy are one scene row: veiled alike
        overlap = slice(max(0, dy), 64 + min(0, dy))
        left_rows = out["left"][overlap, shift:]
        right_rows = out["right"][overlap.start - dy:overlap.stop - dy, :96 - shift]
        np.testing.assert_array_equal(left_rows, right_rows)
        changed += int((out["left"] != texture[y0:y0 + 64, x0:x0 + 96]).any())
    assert changed >= 5


def test_noise_draws_follow_the_docstring():
    aug = StereoAugmentor((80, 120), noise_prob=0.5)
    drawn = [n for n in (aug.draw((200, 300), _rng(seed)).noise for seed in range(400)) if n is not None]
    assert 0.4 < len(drawn) / 400 < 0.6
    assert 0.35 < np.mean([n.floor == 1.0 for n in drawn]) < 0.65
    for n in drawn:
        assert 0.1 <= n.exposure <= 1.0 and 50.0 <= n.full_well <= 3000.0 and 0.001 <= n.read_noise <= 0.015
        assert n.floor == 1.0 or 0.05 <= n.floor <= 0.5
        assert 0.3 <= n.radius <= 0.8 and 0 <= n.centre[0] <= 80 and 0 <= n.centre[1] <= 120


def test_noise_is_shot_and_read_noise_around_the_dimmed_image():
    """On a flat grey crop under uniform light, each view's mean is the dimmed value and its variance
    the Poisson variance plus the read noise's; the two views' noise is independent."""
    linear = 0.2
    grey = np.full((200, 200, 3), np.rint(255 * (1.055 * linear ** (1 / 2.4) - 0.055)), np.uint8)
    noise = NoiseParams(exposure=0.5, full_well=400.0, read_noise=0.01, floor=1.0, centre=(0.0, 0.0), radius=0.5,
                        seed=7)
    left, right = (noise.apply(grey, view).astype(np.float64) / 255 for view in (0, 1))
    decode = [np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4) for v in (left, right)]
    signal = 0.2 * 0.5
    # Poisson(s F) / F has variance s / F; the read noise adds its square
    expected_var = signal / 400.0 + 0.01**2
    for view in decode:
        assert abs(view.mean() - signal) < 0.01 * signal + 0.002
        assert 0.8 < view.var() / expected_var < 1.25
    assert abs(np.corrcoef(decode[0].ravel(), decode[1].ravel())[0, 1]) < 0.03
    np.testing.assert_array_equal(noise.apply(grey, 0), noise.apply(grey, 0))


def test_noise_spot_light_is_brightest_at_its_centre_and_the_same_in_both_views():
    noise = NoiseParams(exposure=1.0, full_well=1e9, read_noise=0.0, floor=0.1, centre=(10.0, 90.0), radius=0.4,
                        seed=1)
    light = noise.light(40, 120)[..., 0]
    assert light.max() == light[10, 90] == pytest.approx(1.0)
    assert light.min() >= 0.1 and light[39, 0] < 0.5
    image = np.full((40, 120, 3), 180, np.uint8)
    # with no noise to speak of, both views are the same dimmed image (up to rounding)
    np.testing.assert_allclose(noise.apply(image, 0), noise.apply(image, 1), atol=1)
    assert noise.apply(image, 0)[39, 0].mean() < noise.apply(image, 0)[10, 90].mean()


@pytest.mark.parametrize("extra", [0, 1, 2, 3, 4, 5])
def test_images_only_just_larger_than_the_crop(pair, extra):
    sample = {k: v[:64 + extra, :96 + extra] for k, v in pair.items()}
    aug = StereoAugmentor((64, 96), **{**OFF, "yjitter": 2})
    for seed in range(12):
        params = aug.draw(sample["left"].shape[:2], _rng(seed))
        (y0, x0), dy = params.origin, params.delta
        assert 0 <= y0 + min(dy, 0) and y0 + max(dy, 0) + 64 <= 64 + extra and x0 + 96 <= 96 + extra
        out = aug.apply(sample, params)
        np.testing.assert_array_equal(out["right"], sample["right"][y0 + dy:y0 + dy + 64, x0:x0 + 96])


@pytest.mark.parametrize("cls", [StereoAugmentor, SparseStereoAugmentor])
@pytest.mark.parametrize("spatial", [True, False])
def test_images_smaller_than_the_crop_are_upscaled(pair, cls, spatial):
    small = {k: v[:20, :30] for k, v in pair.items()}
    aug = cls((64, 96), spatial=spatial)
    for seed in range(4):
        params = aug.draw((20, 30), _rng(seed))
        assert params.size[0] >= 64 and params.size[1] >= 96
        _check_contract(aug(small, _rng(seed)), (64, 96))


# ------------------------------------------------------------------------------ sparse


def test_sparse_scatter_keeps_only_valid_positions_with_scaled_values():
    height, width = 100, 150
    y, x = np.indices((height, width))
    # a value that names its source pixel: 1 + 1e-3 * (y * W + x)
    disparity = (1 + 1e-3 * (y * width + x)).astype(np.float32)
    valid = np.random.default_rng(2).random((height, width)) < 0.3
    sample = {"left": np.zeros((height, width, 3), np.uint8), "right": np.zeros((height, width, 3), np.uint8),
              "disparity": np.where(valid, disparity, 0).astype(np.float32), "valid": valid}
    aug = SparseStereoAugmentor((64, 96), photometric=False, eraser_prob=0.0, patch_prob=0.0, spatial_prob=1.0,
                                scale_range=(0.0, 0.5))
    for seed in range(10):
        params = aug.draw((height, width), _rng(seed))
        (s_y, s_x), (y0, x0) = params.scale, params.origin
        assert s_y == s_x and params.delta == 0
        out = aug.apply(sample, params)
        assert (out["disparity"][~out["valid"]] == 0).all()
        ty, tx = np.nonzero(out["valid"])
        source = np.rint((out["disparity"][ty, tx] / s_x - 1) / 1e-3).astype(int)
        sy, sx = np.divmod(source, width)
        assert valid[sy, sx].all()
        # each output pixel is the nearest resized pixel of its source centre: rint((x + 0.5) s - 0.5)
        np.testing.assert_array_equal(np.rint((sx + 0.5) * s_x - 0.5).astype(int) - x0, tx)
        np.testing.assert_array_equal(np.rint((sy + 0.5) * s_y - 0.5).astype(int) - y0, ty)
        # upscaling (s >= 1) maps distinct sources to distinct pixels, so none is lost
        ly = np.rint((np.nonzero(valid)[0] + 0.5) * s_y - 0.5).astype(int) - y0
        lx = np.rint((np.nonzero(valid)[1] + 0.5) * s_x - 0.5).astype(int) - x0
        assert out["valid"].sum() == ((ly >= 0) & (ly < 64) & (lx >= 0) & (lx < 96)).sum()


def test_sparse_draws_follow_the_spec():
    aug = SparseStereoAugmentor((64, 96))
    params = [aug.draw((300, 400), _rng(seed)) for seed in range(300)]
    resized = np.mean([p.scale != (1.0, 1.0) for p in params])
    assert 0.72 < resized < 0.88
    assert all(p.scale[0] == p.scale[1] and p.delta == 0 for p in params)
    # y0 ~ U{0, H' - crop_h + 19} and x0 ~ U{-50, W' - crop_w + 49}, clipped into the image
    assert all(0 <= p.origin[0] <= p.size[0] - 64 and 0 <= p.origin[1] <= p.size[1] - 96 for p in params)
    assert np.mean([p.origin[1] == 0 for p in params]) > 0.05
    assert np.mean([p.origin[0] == p.size[0] - 64 for p in params]) > 0.02
    with pytest.raises(ArgumentError, match="stretch_prob"):
        SparseStereoAugmentor((64, 96), stretch_prob=0.5)


# ------------------------------------------------------------------------------ errors


def test_nonsense_arguments_raise_named_errors(pair):
    with pytest.raises(ArgumentError, match=r"StereoAugmentor: crop .*\(0, 64\)"):
        StereoAugmentor((0, 64))
    with pytest.raises(ArgumentError, match="crop"):
        SparseStereoAugmentor((32, -1))
    with pytest.raises(ArgumentError, match="eraser_prob"):
        StereoAugmentor((32, 32), eraser_prob=1.5)
    with pytest.raises(ArgumentError, match="veil_prob"):
        StereoAugmentor((32, 32), veil_prob=-0.1)
    with pytest.raises(ArgumentError, match="hue"):
        StereoAugmentor((32, 32), hue=0.7)
    aug = StereoAugmentor((32, 32))
    with pytest.raises(ShapeError, match=r"left=\[120, 180, 3\] right=\[120, 170, 3\]"):
        aug(dict(pair, right=pair["right"][:, :170]), _rng(0))
    with pytest.raises(ShapeError, match=r"\[120, 180\].*disparity=\[120, 179\]"):
        aug(dict(pair, disparity=pair["disparity"][:, :179]), _rng(0))
    with pytest.raises(DTypeError, match="uint8"):
        aug(dict(pair, left=pair["left"].astype(np.float32)), _rng(0))
    with pytest.raises(ArgumentError, match="valid"):
        aug({k: v for k, v in pair.items() if k != "valid"}, _rng(0))
    params = aug.draw((120, 180), _rng(0))
    with pytest.raises(ShapeError, match="params"):
        aug.apply({k: v[:100, :150] for k, v in pair.items()}, params)
    with pytest.raises(ShapeError, match="params"):
        aug.apply(pair, dataclasses.replace(params, origin=(params.size[0], 0)))
    assert isinstance(params, AugmentParams)


# ------------------------------------------------------------------------------ property test


@settings(max_examples=30, deadline=None)
@given(height=st.integers(1, 90), width=st.integers(1, 90), crop_h=st.integers(1, 64), crop_w=st.integers(1, 64),
       sparse=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_any_size_gives_a_well_formed_reproducible_crop(height, width, crop_h, crop_w, sparse, seed):
    rng = np.random.default_rng(seed)
    sample = {"left": rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
              "right": rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
              "disparity": rng.uniform(-5, 600, (height, width)).astype(np.float32),
              "valid": rng.random((height, width)) < 0.7}
    aug = make_augmentor((crop_h, crop_w), sparse=sparse, eraser_prob=0.7, patch_prob=0.7)
    out = aug(sample, np.random.default_rng(seed))
    _check_contract(out, (crop_h, crop_w))
    if sparse:
        assert (out["disparity"][~out["valid"]] == 0).all()
    else:
        assert (np.abs(out["disparity"][out["valid"]]) < 512).all()
    again = aug(sample, np.random.default_rng(seed))
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(out[key], again[key], err_msg=key)
