"""The natural-statistics scene generator (mipnet.data.scenes), its textures and random water."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mipnet.data import GENERATOR_VERSION, SceneStereo, make_scene, scenes, textures
from mipnet.errors import ArgumentError
from mipnet.underwater import JERLOV_KD, PRESETS, WaterParams, random_water

THIN = ("pole", "wire", "branch", "fence")


def _rerender_right_at_disparity(height, width, seed):
    """The noise-free right view evaluated at (x - d, y) for every left pixel, from the scene itself."""
    scene, _ = scenes._compose(seed, height, width, width / 4)
    owner, disparity, x_left = scenes._front(scene.surfaces, "left", height, width)
    x_right = np.arange(width) - disparity
    owner_r, _, x_left_r = scenes._front(scene.surfaces, "right", height, width, x_query=x_right,
                                         shift=(disparity.min(), disparity.max()))
    return scene, owner, x_left, owner_r, x_left_r, scenes._quantise(scenes._shade(scene, owner_r, x_left_r))


# ------------------------------------------------------------------------------ outputs


@pytest.mark.parametrize("size", [(48, 80), (33, 57)])
def test_outputs_dtype_shape_range(size):
    height, width = size
    pair = make_scene(height, width, 3)
    assert pair["left"].shape == pair["right"].shape == (height, width, 3)
    assert pair["left"].dtype == pair["right"].dtype == np.uint8
    assert pair["disparity"].shape == pair["valid"].shape == (height, width)
    assert pair["disparity"].dtype == np.float32 and pair["valid"].dtype == bool
    disparity = pair["disparity"]
    assert np.isfinite(disparity).all() and disparity.min() > 0 and disparity.max() <= width / 4
    # Photometric content is not degenerate: both views use most of the grey range.
    for view in ("left", "right"):
        assert pair[view].std() > 10


def test_deterministic_per_seed_and_different_across_seeds():
    first, again, other = make_scene(40, 64, 11), make_scene(40, 64, 11), make_scene(40, 64, 12)
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(first[key], again[key])
    assert not np.array_equal(first["disparity"], other["disparity"])
    assert not np.array_equal(first["left"], other["left"])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_disparity_is_exact_against_the_noise_free_render(seed):
    height, width = 48, 96
    clean = make_scene(height, width, seed, clean=True)
    _, owner, x_left, owner_r, x_left_r, right_at_d = _rerender_right_at_disparity(height, width, seed)
    valid = clean["valid"]
    assert valid.mean() > 0.5
    # The surface point seen at (x - d, y) in the right view is the left pixel's own point ...
    np.testing.assert_allclose(x_left_r[valid], np.broadcast_to(np.arange(width), valid.shape)[valid], atol=1e-9)
    assert (owner_r == owner)[valid].all()
    # ... so its colour is the left pixel's colour exactly; occluded pixels see another surface.
    np.testing.assert_array_equal(right_at_d[valid], clean["left"][valid])
    inside = ~valid & (np.arange(width) - clean["disparity"] >= 0)
    assert (owner_r != owner)[inside].all()


def test_camera_effects_are_per_view_and_keep_geometry():
    clean, camera = make_scene(48, 96, 5, clean=True), make_scene(48, 96, 5)
    np.testing.assert_array_equal(clean["disparity"], camera["disparity"])
    np.testing.assert_array_equal(clean["valid"], camera["valid"])
    left_change = camera["left"].astype(float) - clean["left"]
    right_change = camera["right"].astype(float) - clean["right"]
    assert 0.5 < np.abs(left_change).mean() < 25 and 0.5 < np.abs(right_change).mean() < 25
    # Independent cameras: the two views' changes (exposure, vignetting, noise) are not the same.
    assert np.abs(left_change - right_change).mean() > 0.5


def _simple_scene(height, width, background_slope):
    """A background with d = 2 + slope * x and an axis-aligned square at d = 10 in front of it."""
    painter = scenes._Painter(np.random.default_rng(0), 1.0)
    square_box = (30.0, 45.0, 10.0, 20.0)
    surfaces = []
    for kind, box, field in (
        ("background", (-2.0, width + 12.0, -2.0, height + 1.0), scenes._Disparity(0.0, 0.0, 2.0, a=background_slope)),
        ("object", square_box, scenes._Disparity(0.0, 0.0, 10.0)),
    ):
        spread = field.spread(box)
        surfaces.append(scenes._Surface(field=field, shape=scenes._Region(box), paint=painter((0, 0), (10, 10), False),
                                        kind=kind, box=box, d_range=(field.c - spread, field.c + spread)))
    scene = scenes._Scene(height=height, width=width, surfaces=tuple(surfaces), cast=np.ones(3))
    return scene, square_box


@pytest.mark.parametrize("slope", [0.0, 0.05])
def test_valid_mask_is_false_exactly_where_occluded_or_outside(slope):
    height, width = 32, 64
    scene, (x0, x1, y0, y1) = _simple_scene(height, width, slope)
    pair = scenes._render(scene, None, clean=True, layers=True)
    y, x = np.indices((height, width))
    in_square = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    disparity = np.where(in_square, 10.0, 2.0 + slope * x)
    np.testing.assert_allclose(pair["disparity"], disparity, rtol=1e-6)
    x_right = x - disparity
    # A background point is hidden where the square's right-view image [x0 - 10, x1 - 10] covers it.
    hidden = ~in_square & (y >= y0) & (y <= y1) & (x_right >= x0 - 10) & (x_right <= x1 - 10)
    expected = (x_right >= 0) & (x_right <= width - 1) & ~hidden
    assert hidden.sum() > 0 and (x_right < 0).sum() > 0
    np.testing.assert_array_equal(pair["valid"], expected)


# ------------------------------------------------------------------------------ content


def test_disparity_histogram_is_long_tailed():
    width = 128
    values = np.concatenate([make_scene(64, width, seed, clean=True)["disparity"].ravel() for seed in range(12)])
    d_max = width / 4
    median, q99 = np.median(values), np.quantile(values, 0.99)
    assert values.max() <= d_max
    assert median < 0.3 * d_max  # many small and medium disparities ...
    assert q99 > 0.5 * d_max  # ... and a tail of large ones
    assert values.mean() > median  # right-skewed
    share_far_half = (values > 0.5 * d_max).mean()
    assert 0.005 < share_far_half < 0.25


def test_max_disparity_option():
    values = np.concatenate([make_scene(48, 96, seed, max_disparity=10.0)["disparity"].ravel() for seed in range(6)])
    assert values.max() <= 10.0 and np.quantile(values, 0.99) > 5.0


def test_thin_structures_are_present_and_thin():
    thin_pixels, narrow_pixels = 0, 0
    for seed in range(8):
        pair = make_scene(96, 160, seed, clean=True, layers=True)
        owner = pair["surface_left"]
        kinds = np.array(pair["surface_kind"])
        thin = np.isin(kinds[owner], THIN)
        # Narrow: both neighbours 2 px away, left and right or above and below, show other surfaces.
        padded = np.pad(owner, 2, mode="edge")
        across_x = (padded[2:-2, :-4] != owner) & (padded[2:-2, 4:] != owner)
        across_y = (padded[:-4, 2:-2] != owner) & (padded[4:, 2:-2] != owner)
        thin_pixels += thin.sum()
        narrow_pixels += (thin & (across_x | across_y)).sum()
    assert thin_pixels > 0.01 * 8 * 96 * 160
    assert narrow_pixels > 0.2 * thin_pixels


def test_scenes_have_many_surfaces_at_many_depths_and_curved_ones():
    for seed in range(4):
        scene, _ = scenes._compose(seed, 96, 160, 40.0)
        pair = make_scene(96, 160, seed, clean=True, layers=True)
        visible = np.unique(pair["surface_left"])
        assert visible.size >= 10
        depths = np.unique(np.round(pair["disparity"]))
        assert depths.size >= 8
    curved = [s for seed in range(4) for s in scenes._compose(seed, 96, 160, 40.0)[0].surfaces
              if s.field.qxx or s.field.qyy]
    assert len(curved) >= 4


def test_deliberately_hard_regions_occur():
    """Textureless, low-contrast and periodic surfaces occur among a few scenes' surfaces."""
    surfaces = [s for seed in range(6) for s in scenes._compose(seed, 96, 160, 40.0)[0].surfaces]
    strength = np.array([np.abs(s.paint.colour).max() for s in surfaces])
    assert (strength < 0.03).any()  # textureless
    assert ((strength > 0.04) & (strength < 0.25)).any()  # low contrast
    assert any(s.paint.texture.name.startswith("periodic") for s in surfaces)


def test_geometry_does_not_depend_on_installed_photographs(monkeypatch):
    installed = textures.available_photos()
    with_photos = make_scene(48, 96, 4)
    monkeypatch.setattr(textures, "available_photos", lambda: ())
    without = make_scene(48, 96, 4)
    np.testing.assert_array_equal(with_photos["disparity"], without["disparity"])
    np.testing.assert_array_equal(with_photos["valid"], without["valid"])
    assert np.array_equal(with_photos["left"], without["left"]) == (not installed)


@settings(max_examples=15, deadline=None)
@given(height=st.integers(6, 48), width=st.integers(6, 80), seed=st.integers(0, 2**32 - 1))
def test_property_any_size_and_seed(height, width, seed):
    pair = make_scene(height, width, seed)
    disparity, valid = pair["disparity"], pair["valid"]
    assert pair["left"].shape == (height, width, 3) and disparity.shape == (height, width)
    assert disparity.min() > 0 and disparity.max() <= width / 4 + 1e-4
    x_right = np.arange(width) - disparity.astype(np.float64)
    assert not valid[(x_right < 0) | (x_right > width - 1)].any()


@settings(max_examples=40, deadline=None)
@given(coefficients=st.lists(st.floats(-1.0, 1.0), min_size=5, max_size=5), d=st.floats(1.0, 60.0),
       half=st.tuples(st.floats(2.0, 80.0), st.floats(2.0, 80.0)))
def test_property_quadratic_field_inverse(coefficients, d, half):
    """left_x inverts x - d(x, y) in closed form for any fitted (slanted, curved) field."""
    a, b, qxx, qxy, qyy = coefficients
    box = (50.0 - half[0], 50.0 + half[0], 40.0 - half[1], 40.0 + half[1])
    raw = scenes._Disparity(50.0, 40.0, d, a=a, b=b, qxx=qxx / half[0], qxy=qxy / half[0], qyy=qyy / half[1])
    field = scenes._fit(raw, box, 0.5, 80.0, 0.6)
    assert field.x_slope(box) <= 0.5 + 1e-12
    y, x = np.meshgrid(np.linspace(box[2], box[3], 9), np.linspace(box[0], box[1], 9), indexing="ij")
    disparity = field(x, y)
    assert (disparity >= 0.5 - 1e-9).all() and (disparity <= 80.0 + 1e-9).all()
    np.testing.assert_allclose(field.left_x(x - disparity, y), x, atol=1e-8)


# ------------------------------------------------------------------------------ textures


def test_procedural_tiles_are_fixed_and_pink_noise_has_a_power_law_spectrum():
    tile = textures.procedural("pink", 3)
    assert tile is textures.procedural("pink", 3) and tile.periodic
    rgb = tile.levels[0].view(np.uint8).reshape(*tile.size, 4)[..., :3].astype(float)
    grey = rgb.mean(axis=2) - rgb.mean()
    power = np.abs(np.fft.fft2(grey)) ** 2
    fy, fx = np.meshgrid(np.fft.fftfreq(grey.shape[0]), np.fft.fftfreq(grey.shape[1]), indexing="ij")
    radius = np.hypot(fx, fy)
    band = (radius > 0.01) & (radius < 0.25)
    slope = np.polyfit(np.log(radius[band]), np.log(power[band] + 1e-12), 1)[0]
    assert -3.2 < slope < -1.2  # power ~ f^-2 alpha, alpha in [0.8, 1.4] (an anisotropic tile bends it)
    with pytest.raises(ArgumentError):
        textures.procedural("marble", 0)
    with pytest.raises(ArgumentError):
        textures.procedural("pink", textures.TILES_PER_KIND)


def test_dead_leaves_tile_is_piecewise_constant():
    tile = textures.procedural("leaves", 0)
    rgb = tile.levels[0].view(np.uint8).reshape(*tile.size, 4)[..., :3].astype(int)
    step = np.abs(np.diff(rgb, axis=1)).max(axis=2)
    # Most neighbours lie in the same leaf (flat colour, maybe fine texture); edges are a minority.
    assert np.median(step) < 12 and (step > 30).mean() > 0.01


def test_photographs_listed_with_licences_and_loadable():
    names = {entry[3] for entry in textures.PHOTOS}
    assert all(entry[4] for entry in textures.PHOTOS)
    available = textures.available_photos()
    assert set(available) <= names
    assert "motorcycle" not in " ".join(entry[2] for entry in textures.PHOTOS)  # evaluation data stays out
    if available:
        image = textures.photo(available[0])
        assert not image.periodic and min(image.size) >= 16 and max(image.size) <= 512
        assert "photos:" in GENERATOR_VERSION
    else:
        assert GENERATOR_VERSION.endswith("procedural-only")
    with pytest.raises(ArgumentError):
        textures.photo("no-such-photo")


# ------------------------------------------------------------------------------ dataset


def test_dataset_items_seeds_and_meta():
    dataset = SceneStereo(3, 40, 64, seed=20)
    assert len(dataset) == 3
    item = dataset[1]
    reference = make_scene(40, 64, 21)
    for key in ("left", "right", "disparity", "valid"):
        np.testing.assert_array_equal(item[key], reference[key])
    assert item["meta"]["dataset"] == "scenes" and item["meta"]["seed"] == 21 and item["meta"]["index"] == 1
    assert item["meta"]["underwater"] is None and item["meta"]["generator"] == GENERATOR_VERSION
    np.testing.assert_array_equal(dataset[-1]["disparity"], make_scene(40, 64, 22)["disparity"])
    with pytest.raises(IndexError):
        dataset[3]


def test_seed_split_guard():
    start = scenes.EVAL_SEED_START
    with pytest.raises(ArgumentError, match="straddle"):
        SceneStereo(10, 32, 48, seed=start - 5)
    assert len(SceneStereo(10, 32, 48, seed=start - 10)) == 10  # last seed start - 1: all training
    assert len(SceneStereo(10, 32, 48, seed=start)) == 10
    assert len(SceneStereo(0, 32, 48, seed=start - 1)) == 0


@pytest.mark.parametrize("underwater", ["random", "turbid", {"preset": "clear", "gain": 0.5},
                                        dataclasses.replace(PRESETS["coastal"], depth=12.0)])
def test_underwater_variants_change_images_but_not_geometry(underwater):
    air, water = SceneStereo(2, 40, 64, seed=30), SceneStereo(2, 40, 64, seed=30, underwater=underwater)
    for index in range(2):
        dry, wet = air[index], water[index]
        np.testing.assert_array_equal(dry["disparity"], wet["disparity"])
        np.testing.assert_array_equal(dry["valid"], wet["valid"])
        assert np.abs(dry["left"].astype(float) - wet["left"]).mean() > 2
        assert wet["meta"]["underwater"] is not None
    np.testing.assert_array_equal(water[1]["left"], water[1]["left"])


def test_random_underwater_draws_differ_per_item():
    water = SceneStereo(2, 32, 48, seed=40, underwater="random")
    assert water[0]["meta"]["underwater"] == "random"
    first, second = (random_water(np.random.default_rng([seed, 2])) for seed in (40, 41))
    assert first != second


def test_random_water_ranges_and_determinism():
    for name in PRESETS:
        base = PRESETS[name]
        for seed in range(20):
            water = random_water(np.random.default_rng(seed), name)
            assert isinstance(water, WaterParams)
            assert water == random_water(np.random.default_rng(seed), name)
            classes = list(JERLOV_KD)
            assert abs(classes.index(water.water_type) - classes.index(base.water_type)) <= 1
            low, high = np.clip([base.scattering * 0.5, base.scattering * 2.0], 0.005, 1.5)
            assert low - 1e-12 <= water.scattering <= high + 1e-12
            assert 0.5 <= water.depth <= 40.0 and 100.0 <= water.full_well <= 5000.0
            assert 0.5 * base.baseline - 1e-12 <= water.baseline <= 2.0 * base.baseline + 1e-12
            assert all(0.01 <= v <= 0.9 for v in water.veiling_light)
            assert water.fx == base.fx and (water.z_min, water.z_max) == (base.z_min, base.z_max)
    drawn = {random_water(np.random.default_rng(seed)).water_type for seed in range(40)}
    assert len(drawn) >= 4  # around all presets, not one
    with pytest.raises(ArgumentError, match="random_water"):
        random_water(np.random.default_rng(0), "lake")
    with pytest.raises(ArgumentError, match="random_water"):
        random_water(0)


@pytest.mark.parametrize("call", [
    lambda: make_scene(0, 10, 1),
    lambda: make_scene(10, 10.5, 1),
    lambda: make_scene(10, 10, -1),
    lambda: make_scene(10, 10, 1, max_disparity=0.0),
    lambda: make_scene(10, 10, 1, max_disparity=11.0),
    lambda: SceneStereo(-1, 10, 10),
    lambda: SceneStereo(2, 10, 10, underwater="lake"),
    lambda: SceneStereo(2, 10, 10, underwater={"preset": "clear", "murk": 1.0}),
])
def test_bad_arguments_raise_argument_errors(call):
    with pytest.raises(ArgumentError):
        call()
