"""Raw pairs from a calibrated rig (mipnet.stereo.rectify, ``mipnet infer --calib rig.yml``).

The pair is rendered from a known scene: a slanted plane with a procedural colour texture, 0.65-0.75 m in front of
the left camera, seen through two cameras with known intrinsics, radial/tangential distortion and a known rotation
and translation (baseline 0.12 m), as a real rig's raw footage would be. Every pixel of each raw image is traced
back through the distortion (``cv2.undistortPoints`` iterated to convergence) to its ray, intersected with the
plane, and coloured from the texture (2x2 supersampling). The depth goal is checked on the rectified left view
over the textured pixels away from the borders: at least 16 px from every edge, with their match inside the right
image, and a local (7x7) grey-level standard deviation of at least 4.
"""

import os

import numpy as np
import pytest

import mipnet
from helpers import require
from mipnet.cli import main
from mipnet.errors import ArgumentError, FormatError, ShapeError
from mipnet.stereo import io
from mipnet.stereo.rectify import Rectifier, StereoRig, is_rig_calibration, open_calibration

cv2 = require("cv2")

H, W = 192, 256
K1 = np.array([[262.0, 0.0, 129.0], [0.0, 260.0, 97.5], [0.0, 0.0, 1.0]])
K2 = np.array([[258.0, 0.0, 125.0], [0.0, 257.0, 99.0], [0.0, 0.0, 1.0]])
D1 = np.array([[-0.12, 0.06, 0.0012, -0.0008, -0.01]])
D2 = np.array([[-0.10, 0.04, -0.0009, 0.0010, 0.0]])
ROTATION_VECTOR = np.array([0.012, -0.025, 0.008])  # about 1.6 degrees between the two cameras
T = np.array([[-0.12], [0.003], [0.002]])  # metres: the second camera 12 cm to the right
PLANE_NORMAL = np.array([0.12, -0.08, 1.0]) / np.linalg.norm([0.12, -0.08, 1.0])
PLANE_OFFSET = float(PLANE_NORMAL @ [0.0, 0.0, 0.7])  # the plane n . X = c passes 0.7 m ahead of the left camera
TEXTURE_SIZE, TEXTURE_EXTENT = 1024, 2.0  # texels, metres: a texel is ~2 mm, a pixel at 0.65 m ~2.5 mm
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
BORDER, MIN_TEXTURE_STD = 16, 4.0


def rotation() -> np.ndarray:
    return cv2.Rodrigues(ROTATION_VECTOR)[0]


def texture(seed: int) -> np.ndarray:
    """(TEXTURE_SIZE, TEXTURE_SIZE, 3) float32 colour noise at three scales (1, 3, 9 texels), grey 128 +- 40."""
    rng = np.random.default_rng(seed)
    channels = []
    for _ in range(3):
        channel = np.zeros((TEXTURE_SIZE, TEXTURE_SIZE), np.float32)
        for sigma, weight in ((1.0, 1.0), (3.0, 0.8), (9.0, 0.6)):
            layer = cv2.GaussianBlur(rng.standard_normal((TEXTURE_SIZE, TEXTURE_SIZE)).astype(np.float32), (0, 0),
                                     sigma)
            channel += weight * layer / layer.std()
        channels.append(channel)
    return np.clip(128 + 40 * np.stack(channels, -1), 0, 255).astype(np.float32)


def plane_axes() -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis (e1, e2) of the plane, for its texture coordinates."""
    e1 = np.cross([0.0, 1.0, 0.0], PLANE_NORMAL)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(PLANE_NORMAL, e1)


def render(colours: np.ndarray, k: np.ndarray, d: np.ndarray, rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """The raw (distorted) (H, W, 3) uint8 image of the textured plane seen by a camera with intrinsics ``k``,
    distortion ``d`` and pose X_cam = rot @ X_left + trans."""
    e1, e2 = plane_axes()
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    origin = -rot.T @ trans.reshape(3)  # the camera centre in the left camera's frame
    total = np.zeros((H, W, 3), np.float32)
    for dy, dx in ((-0.25, -0.25), (-0.25, 0.25), (0.25, -0.25), (0.25, 0.25)):
        pixels = np.stack([xs + dx, ys + dy], -1).reshape(-1, 1, 2)
        normalised = cv2.undistortPoints(pixels, k, d, criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
        # ray directions in the left frame: rot^T @ (x, y, 1), as rows (x, y, 1) @ rot
        rays = np.concatenate([normalised, np.ones((len(normalised), 1))], 1) @ rot
        # ray-plane intersection: n . (o + t r) = c
        t = (PLANE_OFFSET - PLANE_NORMAL @ origin) / (rays @ PLANE_NORMAL)
        points = origin + t[:, None] * rays
        # plane coordinates (metres) -> texel coordinates, the plane's origin at the texture's centre
        tex_x = ((points @ e1) / TEXTURE_EXTENT + 0.5) * TEXTURE_SIZE
        tex_y = ((points @ e2) / TEXTURE_EXTENT + 0.5) * TEXTURE_SIZE
        total += cv2.remap(colours, tex_x.reshape(H, W).astype(np.float32), tex_y.reshape(H, W).astype(np.float32),
                           cv2.INTER_LINEAR)
    return np.clip(total / 4 + 0.5, 0, 255).astype(np.uint8)


def write_rig(path, image_size=(H, W), **replace) -> None:
    """A cv2.FileStorage calibration of the rig (keys K1 D1 K2 D2 R T, image_width/height); ``replace`` swaps or
    (value None) drops entries."""
    entries = {"K1": K1, "D1": D1, "K2": K2, "D2": D2, "R": rotation(), "T": T}
    entries.update(replace)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        if value is not None:
            storage.write(key, np.asarray(value, dtype=np.float64))
    if image_size is not None:
        storage.write("image_width", image_size[1])
        storage.write("image_height", image_size[0])
    storage.release()


def true_depth(rectification) -> np.ndarray:
    """(H, W) depth of the plane along the rectified left camera's axis at every rectified left pixel."""
    p1 = rectification.P1
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    # the rectified ray of pixel (u, v), z = 1: ((u - cx) / fx, (v - cy) / fy, 1)
    rays = np.stack([(xs - p1[0, 2]) / p1[0, 0], (ys - p1[1, 2]) / p1[1, 1], np.ones_like(xs)], -1)
    # in the raw left frame R1^T @ ray (rows: ray @ R1); the plane meets it at t = c / (n . ray), where Z_rect = t
    return PLANE_OFFSET / ((rays @ rectification.R1) @ PLANE_NORMAL)


def evaluated_pixels(rectified_left: np.ndarray, depth: np.ndarray, focal: float, baseline: float) -> np.ndarray:
    """(H, W) bool: textured pixels at least BORDER px from every edge whose match lies inside the right image."""
    grey = cv2.cvtColor(rectified_left, cv2.COLOR_RGB2GRAY).astype(np.float32)
    # local standard deviation sqrt(E[g^2] - E[g]^2) over 7x7 windows
    std = np.sqrt(np.maximum(cv2.blur(grey * grey, (7, 7)) - cv2.blur(grey, (7, 7)) ** 2, 0))
    xs = np.arange(W)[None, :]
    keep = np.zeros((H, W), bool)
    keep[BORDER:H - BORDER, BORDER:W - BORDER] = True
    # the match of u in the right image is u - d with d = f B / Z
    return keep & (xs - focal * baseline / depth >= BORDER) & (std >= MIN_TEXTURE_STD)


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The raw pair (left.png, right.png) and its calibration rig.yml in one folder."""
    folder = tmp_path_factory.mktemp("rig")
    colours = texture(seed=7)
    io.write_image(folder / "left.png", render(colours, K1, D1, np.eye(3), np.zeros(3)))
    io.write_image(folder / "right.png", render(colours, K2, D2, rotation(), T))
    write_rig(folder / "rig.yml")
    return folder


def test_infer_calib_rig_gives_depth_within_one_percent(rig, tmp_path):
    out = tmp_path / "out"
    assert main(["infer", "-l", str(rig / "left.png"), "-r", str(rig / "right.png"), "-o", str(out),
                 "--calib", str(rig / "rig.yml")]) == 0
    depth, disp = np.load(out / "left_depth.npy"), np.load(out / "left_disp.npy")
    rectified_left = io.read_image(out / "left_rectified.png")
    rectification = Rectifier(rig / "rig.yml").rectification((H, W))
    focal, baseline = rectification.focal, rectification.baseline
    np.testing.assert_array_equal(
        rectified_left, Rectifier(rig / "rig.yml").rectify(io.read_image(rig / "left.png"),
                                                            io.read_image(rig / "right.png")).left)
    assert baseline == pytest.approx(np.linalg.norm(T), rel=1e-6)  # the rectified baseline is |T|, in metres
    np.testing.assert_allclose(depth, focal * baseline / disp, rtol=1e-5)  # Z = f B / d, d in the rectified frame

    truth = true_depth(rectification)
    evaluated = evaluated_pixels(rectified_left, truth, focal, baseline)
    relative_error = np.abs(depth - truth)[evaluated] / truth[evaluated]
    assert evaluated.mean() > 0.5, "the evaluated pixels should cover most of the image"
    assert np.median(relative_error) < 0.01 and relative_error.mean() < 0.01, (
        f"depth error over {evaluated.sum()} pixels: median {np.median(relative_error):.4f}, "
        f"mean {relative_error.mean():.4f}")
    assert (out / "left_points.ply").read_bytes().startswith(b"ply\n")
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]


def plane_points(count: int, seed: int) -> np.ndarray:
    """(count, 3) points of the plane that both cameras see, in the left camera's frame."""
    rng = np.random.default_rng(seed)
    e1, e2 = plane_axes()
    centre = PLANE_OFFSET * PLANE_NORMAL
    coords = rng.uniform(-0.2, 0.2, size=(count, 2))
    return centre + coords[:, :1] * e1 + coords[:, 1:] * e2


def project(points: np.ndarray, k, d, rot, trans) -> np.ndarray:
    """(N, 2) raw (distorted) pixel positions of 3-D points, by cv2.projectPoints."""
    return cv2.projectPoints(points, cv2.Rodrigues(rot)[0], np.asarray(trans, np.float64).reshape(3), k,
                             d)[0].reshape(-1, 2)


def test_rectified_correspondences_share_a_row_and_the_maps_agree(rig):
    rectification = Rectifier(rig / "rig.yml").rectification((H, W))
    points = plane_points(200, seed=3)
    raw_left = project(points, K1, D1, np.eye(3), np.zeros(3))
    raw_right = project(points, K2, D2, rotation(), T)
    inside = np.all((raw_left > 2) & (raw_left < [W - 3, H - 3]) & (raw_right > 2) & (raw_right < [W - 3, H - 3]),
                    axis=1)
    raw_left, raw_right, points = raw_left[inside], raw_right[inside], points[inside]
    assert len(points) > 50
    assert np.abs(raw_left[:, 1] - raw_right[:, 1]).max() > 1.0  # the raw pair is not row-aligned
    rect_left, rect_right = rectification.rectify_points(raw_left, 0), rectification.rectify_points(raw_right, 1)
    assert np.abs(rect_left[:, 1] - rect_right[:, 1]).max() < 0.01  # the goal is < 0.5 px; OpenCV gives ~1e-9
    # the disparity of a rectified correspondence is f B / Z, Z along the rectified axis (R1 @ X)[2]
    z_rectified = (points @ rectification.R1.T)[:, 2]
    np.testing.assert_allclose(rect_left[:, 0] - rect_right[:, 0],
                               rectification.focal * rectification.baseline / z_rectified, atol=0.01)
    # the remap tables send each rectified position back to its raw position (bilinear in the tables)
    for camera, rect, raw in ((0, rect_left, raw_left), (1, rect_right, raw_right)):
        map_x, map_y = rectification.maps[camera]
        sampled = [cv2.remap(m, rect[:, :1].astype(np.float32), rect[:, 1:].astype(np.float32), cv2.INTER_LINEAR)
                   for m in (map_x, map_y)]
        np.testing.assert_allclose(np.concatenate(sampled, 1), raw, atol=0.02)


def test_alpha_trades_black_borders_for_field_of_view(rig):
    left, right = io.read_image(rig / "left.png"), io.read_image(rig / "right.png")
    tight = Rectifier(rig / "rig.yml").rectify(left, right)
    wide = Rectifier(rig / "rig.yml", alpha=1.0).rectify(left, right)
    black = [np.mean(np.all(image == 0, axis=-1)) for image in (tight.left, tight.right, wide.left, wide.right)]
    assert max(black[:2]) < 0.001 and min(black[2:]) > 0.01
    assert wide.focal < tight.focal and wide.baseline == pytest.approx(tight.baseline)


def test_python_api_rectify_and_depth(rig):
    left, right = io.read_image(rig / "left.png"), io.read_image(rig / "right.png")
    rectifier = Rectifier(StereoRig.read(rig / "rig.yml"))
    pair = mipnet.rectify(left, right, rig / "rig.yml")
    again = rectifier.rectify(left, right)
    np.testing.assert_array_equal(pair.left, again.left)
    np.testing.assert_array_equal(pair.right, again.right)
    assert (pair.focal, pair.baseline) == (again.focal, again.baseline)
    assert rectifier.rectification((H, W)) is rectifier.rectification((H, W))  # maps computed once per size
    disparity = np.full((H, W), 20.0, np.float32)
    disparity[0, 0] = 0.0
    depth = rectifier.depth(disparity)
    assert depth[0, 0] == np.inf and depth[1, 1] == pytest.approx(pair.focal * pair.baseline / 20.0, rel=1e-6)
    gray = rectifier.rectify(left[..., 0], right[..., 0])
    np.testing.assert_array_equal(gray.left, pair.left[..., 0])


def test_xml_json_and_opencv_sample_names_read_the_same_rig(rig, tmp_path):
    reference = Rectifier(rig / "rig.yml").rectification((H, W))
    write_rig(tmp_path / "rig.xml")
    write_rig(tmp_path / "rig.json", image_size=None)
    # a hand-written JSON: OpenCV stereo_calib's names M1/M2, plain lists, R as a Rodrigues vector, T as a row
    (tmp_path / "hand.json").write_text(
        '{"M1": %s, "D1": %s, "M2": %s, "D2": %s, "R": %s, "T": %s}'
        % tuple(str(np.asarray(v).tolist()) for v in (K1, D1[0], K2, D2[0], ROTATION_VECTOR, T[:, 0])))
    for name in ("rig.xml", "rig.json", "hand.json"):
        assert is_rig_calibration(tmp_path / name)
        rectification = Rectifier(tmp_path / name).rectification((H, W))
        np.testing.assert_allclose(rectification.P1, reference.P1, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(rectification.P2, reference.P2, rtol=1e-9, atol=1e-9)
    assert StereoRig.read(tmp_path / "rig.json").image_size is None
    assert StereoRig.read(rig / "rig.yml").image_size == (H, W)


@pytest.mark.parametrize("replace, expected", [
    ({"T": None}, ["'T' entry", "it has: K1, D1, K2, D2, R"]),
    ({"K2": None}, ["'K2' entry (or M2, cameraMatrix2)"]),
    ({"K1": np.eye(3)[:2]}, ["K1 must be a 3x3 camera matrix, got shape [2, 3]"]),
    ({"D2": np.zeros((1, 3))}, ["D2 must be a vector of 4 or 5 or 8 or 12 or 14 numbers", "[1, 3]"]),
    ({"T": np.zeros((2, 2))}, ["T must be a vector of 3 numbers", "[2, 2]"]),
    ({"R": np.diag([1.0, 1.0, 2.0])}, ["R is not a rotation matrix"]),
    ({"K1": np.array([[262.0, 0, 129], [0, 260, 97.5], [0, 0, 0]])}, ["K1 is not a camera matrix"]),
    ({"T": np.zeros((3, 1))}, ["T is zero"]),
])
def test_a_wrong_calibration_is_one_error_naming_file_and_entry(tmp_path, replace, expected):
    write_rig(tmp_path / "rig.yml", **replace)
    with pytest.raises(FormatError) as info:
        StereoRig.read(tmp_path / "rig.yml")
    message = str(info.value)
    assert message.startswith(str(tmp_path / "rig.yml")) and all(text in message for text in expected), message


def test_unreadable_and_half_sized_calibrations_are_errors(tmp_path):
    (tmp_path / "broken.yml").write_text("%YAML:1.0\nK1: [1, 2\n")
    with pytest.raises(FormatError, match="broken.yml: not a YAML/XML/JSON file cv2.FileStorage can read"):
        StereoRig.read(tmp_path / "broken.yml")
    write_rig(tmp_path / "width_only.yml", image_size=None)
    with open(tmp_path / "width_only.yml", "a") as f:
        f.write("image_width: 256\n")
    with pytest.raises(FormatError, match="width_only.yml: .*has image_width but lacks the 'image_height' entry"):
        StereoRig.read(tmp_path / "width_only.yml")
    with pytest.raises(FileNotFoundError):
        StereoRig.read(tmp_path / "absent.yml")


def test_rigs_mipnet_cannot_match_are_refused(tmp_path):
    write_rig(tmp_path / "swapped.yml", T=-T)
    with pytest.raises(FormatError, match="swapped.yml: the second camera is LEFT of the first"):
        Rectifier(tmp_path / "swapped.yml").rectification((H, W))
    write_rig(tmp_path / "vertical.yml", T=np.array([[0.003], [-0.12], [0.0]]))
    with pytest.raises(FormatError, match="vertical.yml: the cameras are one above the other"):
        Rectifier(tmp_path / "vertical.yml").rectification((H, W))
    with pytest.raises(ArgumentError, match=r"alpha .* must be in \[0, 1\], got 1.5"):
        Rectifier(StereoRig(K1, D1, K2, D2, rotation(), T), alpha=1.5)


def test_a_pair_of_another_size_than_the_calibration_is_refused(rig, tmp_path, capsys):
    small = io.read_image(rig / "left.png")[:160]
    with pytest.raises(ShapeError, match=r"rig.yml: the calibration is for 192x256 \(HxW\) images but the pair is "
                                         r"160x256"):
        mipnet.rectify(small, small, rig / "rig.yml")
    with pytest.raises(ShapeError, match=r"must be \(H, W\) or \(H, W, C\) of one shape, got \[192, 256, 3\] and "
                                         r"\[160, 256, 3\]"):
        mipnet.rectify(io.read_image(rig / "left.png"), small, rig / "rig.yml")
    io.write_image(tmp_path / "small_left.png", small)
    io.write_image(tmp_path / "small_right.png", small)
    code = main(["infer", "-l", str(tmp_path / "small_left.png"), "-r", str(tmp_path / "small_right.png"),
                 "-o", str(tmp_path / "out"), "--calib", str(rig / "rig.yml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "rig.yml: the calibration is for 192x256 (HxW) images" in err[0], err


def test_cli_names_the_missing_entry_and_checks_rectify_alpha(rig, tmp_path, capsys):
    write_rig(tmp_path / "no_r.yml", R=None)
    pair = ["-l", str(rig / "left.png"), "-r", str(rig / "right.png"), "-o", str(tmp_path / "out")]
    cases = [
        (["--calib", str(tmp_path / "no_r.yml")], ["no_r.yml", "lacks the 'R' entry"]),
        (["--rectify-alpha", "0.5"], ["--rectify-alpha needs --calib"]),
        (["--calib", str(rig / "rig.yml"), "--rectify-alpha", "2"], ["alpha", "must be in [0, 1], got 2.0"]),
    ]
    (tmp_path / "K.txt").write_text("300 0 32 0 300 24 0 0 1\n0.1\n")
    cases.append((["--calib", str(tmp_path / "K.txt"), "--rectify-alpha", "0.5"],
                  ["K.txt", "alpha applies to an OpenCV stereo rig calibration"]))
    for extra, expected in cases:
        assert main(["infer", *pair, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("mipnet infer: error: "), err
        assert all(text in err[0] for text in expected), err[0]


def test_text_calibrations_stay_on_the_rectified_path(tmp_path):
    (tmp_path / "calib.txt").write_text("cam0=[300 0 32; 0 300 24; 0 0 1]\ncam1=[300 0 40; 0 300 24; 0 0 1]\n"
                                        "baseline=100\n")
    (tmp_path / "K.txt").write_text("300 0 32 0 300 24 0 0 1\n0.1\n")
    for name in ("calib.txt", "K.txt"):
        assert not is_rig_calibration(tmp_path / name)
        assert open_calibration(tmp_path / name) == io.read_calib(tmp_path / name)
    (tmp_path / "rig.cal").write_text("%YAML:1.0\n---\nK1: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n")
    assert is_rig_calibration(tmp_path / "rig.cal")
