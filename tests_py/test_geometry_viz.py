"""mipnet.stereo.geometry (disparity -> depth -> points) and mipnet.stereo.viz (colour maps)."""

import numpy as np
import pytest
from mipnet.stereo.geometry import baseline_in_metres, depth_to_points, disparity_to_depth
from mipnet.stereo.io import read_calib, write_ply
from mipnet.stereo.viz import COLORMAPS, colorize, colormap_lut

MIDDLEBURY = {"fx": 1000.0, "fy": 1000.0, "cx": 1.0, "cy": 0.5, "doffs": 10.0, "baseline": 100.0,
              "baseline_unit": "mm"}


def test_disparity_to_depth_middlebury_units_and_doffs():
    disp = np.array([[40.0, 90.0], [0.0, -5.0]], dtype=np.float32)
    depth = disparity_to_depth(disp, MIDDLEBURY)
    assert depth.dtype == np.float32
    # 1000 px * 0.1 m / (40 + 10) px = 2 m; / (90 + 10) = 1 m
    assert depth[0, 0] == pytest.approx(2.0) and depth[0, 1] == pytest.approx(1.0)
    assert np.isposinf(depth[1]).all()


def test_disparity_to_depth_k_txt_metres_and_invalid_values(tmp_path):
    (tmp_path / "K.txt").write_text("500 0 2 0 500 1 0 0 1\n0.2\n")
    calib = read_calib(tmp_path / "K.txt")
    depth = disparity_to_depth(np.array([50.0, np.nan, np.inf, 0.0]), calib)
    assert depth[0] == pytest.approx(2.0)  # 500 * 0.2 / 50
    assert np.isposinf(depth[1:]).all()


def test_disparity_to_depth_negative_doffs_sum_is_infinite():
    calib = dict(MIDDLEBURY, doffs=-50.0)
    assert np.isposinf(disparity_to_depth(np.array([40.0]), calib)[0])


def test_baseline_units():
    assert baseline_in_metres({"baseline": 120.0, "baseline_unit": "mm"}) == pytest.approx(0.12)
    assert baseline_in_metres({"baseline": 12.0, "baseline_unit": "cm"}) == pytest.approx(0.12)
    assert baseline_in_metres({"baseline": 0.12}) == pytest.approx(0.12)
    with pytest.raises(ValueError):
        baseline_in_metres({"baseline": 1.0, "baseline_unit": "inch"})


def test_depth_to_points_by_hand():
    depth = np.array([[2.0, 4.0, np.inf], [1.0, 0.0, 3.0]])
    calib = {"fx": 2.0, "fy": 4.0, "cx": 1.0, "cy": 0.5}
    image = np.arange(18, dtype=np.uint8).reshape(2, 3, 3)
    points, colors = depth_to_points(depth, calib, image=image)
    # (u, v, Z) -> ((u - 1) Z / 2, (v - 0.5) Z / 4, Z) for the 4 finite positive pixels, row-major
    expected = [[-1.0, -0.25, 2.0], [0.0, -0.5, 4.0], [-0.5, 0.125, 1.0], [1.5, 0.375, 3.0]]
    np.testing.assert_allclose(points, expected)
    assert points.dtype == np.float32 and colors.dtype == np.uint8
    np.testing.assert_array_equal(colors, image.reshape(-1, 3)[[0, 1, 3, 5]])


def test_depth_to_points_valid_mask_z_far_gray_and_defaults():
    depth = np.full((2, 2), 5.0)
    depth[1, 1] = 50.0
    valid = np.array([[True, False], [True, True]])
    points, colors = depth_to_points(depth, {"fx": 10.0}, image=np.full((2, 2), 9, np.uint8), valid=valid, z_far=10)
    assert len(points) == 2
    np.testing.assert_allclose(points[0], [-0.25, -0.25, 5.0])  # default centre (0.5, 0.5)
    np.testing.assert_array_equal(colors, 9)
    assert depth_to_points(depth, {"fx": 10.0})[1] is None


def test_disparity_to_ply_pipeline(tmp_path):
    disp = np.full((3, 4), 50.0, np.float32)
    points, colors = depth_to_points(disparity_to_depth(disp, MIDDLEBURY), MIDDLEBURY,
                                     image=np.zeros((3, 4, 3), np.uint8))
    write_ply(tmp_path / "cloud.ply", points, colors)
    assert b"element vertex 12\n" in (tmp_path / "cloud.ply").read_bytes()[:200]
    assert np.allclose(points[:, 2], 100.0 / 60.0)


# ------------------------------------------------------------------------------------ viz


def test_colorize_shape_range_and_invalid_black():
    disp = np.linspace(0, 10, 20, dtype=np.float32).reshape(4, 5)
    disp[0, 0] = np.nan
    valid = np.ones((4, 5), bool)
    valid[3, 4] = False
    out = colorize(disp, vmin=0, vmax=10, valid=valid)
    assert out.shape == (4, 5, 3) and out.dtype == np.uint8
    assert (out[0, 0] == 0).all() and (out[3, 4] == 0).all()
    lut = colormap_lut("turbo")
    np.testing.assert_array_equal(out[3, 3], lut[round(disp[3, 3] / 10 * 255)])


def test_colorize_clips_and_default_percentiles():
    values = np.arange(101, dtype=np.float64).reshape(1, 101)  # 1st percentile 1, 99th 99
    out = colorize(values, cmap="gray")
    assert (out[0, 0] == 0).all() and (out[0, 1] == 0).all()
    assert (out[0, 99] == 255).all() and (out[0, 100] == 255).all()
    assert out[0, 50, 0] == round((50 - 1) / 98 * 255)
    assert (colorize(np.full((2, 2), np.nan)) == 0).all()
    assert (colorize(np.ones((2, 2)), cmap="jet") > 0).any()  # constant image: no division by zero


def test_turbo_lut_shape_and_landmarks():
    lut = colormap_lut("turbo")
    assert lut.shape == (256, 3) and lut.dtype == np.uint8
    assert lut[0, 2] > lut[0, 1]  # dark blue-purple start
    assert lut[128, 1] > 200  # bright green-yellow middle
    assert lut[255, 0] > 3 * lut[255, 2]  # dark red end
    assert not lut.flags.writeable


def test_unknown_colormap_raises():
    assert "turbo" in COLORMAPS
    with pytest.raises(ValueError, match="unknown colour map"):
        colorize(np.zeros((2, 2)), cmap="viridis-ish")
