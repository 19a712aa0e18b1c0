"""``mipnet infer --video / --sbs / --sequence`` (:mod:`mipnet.cli.stream`, :mod:`mipnet.stereo.video`): every frame's
disparity from a warm-started stream, PNGs and an mp4 in one colour range, and a clear error for bad input."""

import json

import numpy as np
import pytest

import mipnet
from helpers import require
from mipnet.cli import main
from mipnet.data.sequences import make_sequence
from mipnet.errors import ShapeError
from mipnet.stereo import io
from mipnet.stereo.video import DisparityVideo, pooled_percentiles, read_colour_range, read_frames
from mipnet.stereo.viz import colorize

ITERS = ["--iters", "1", "1", "--warm-iters", "1", "1"]
FRAMES, SIZE = 6, (64, 96)


def _write_video(path, frames, fps=10, pix_fmt="yuv420p"):
    """An H.264 mp4 of RGB uint8 frames, written with PyAV (4:4:4 for an odd width)."""
    av = require("av")
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = pix_fmt
        stream.options = {"crf": "10"}
        for frame in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A generated moving-camera clip as two mp4s, one side-by-side mp4 and two PNG sequences."""
    require("av")
    folder = tmp_path_factory.mktemp("clip")
    frames = make_sequence(1_000_003, frames=FRAMES, size=SIZE)
    _write_video(folder / "L.mp4", [f["left"] for f in frames])
    _write_video(folder / "R.mp4", [f["right"] for f in frames])
    _write_video(folder / "S.mp4", [np.concatenate([f["left"], f["right"]], axis=1) for f in frames])
    for side in ("left", "right"):
        (folder / side).mkdir()
        for t, frame in enumerate(frames):
            io.write_image(folder / side / f"f{t:03d}.png", frame[side])
    return folder


def _streamed(lefts, rights):
    stream = mipnet.Stream(mipnet.MIPNet.pretrained(), (1, 1), cold_iters=(1, 1))
    return [stream(left, right) for left, right in zip(lefts, rights)]


def _check_percentiles(values, found, percentiles=(1, 99), bins=4096):
    """Each found percentile p is the upper edge of the histogram bin holding the ceil(p n / 100)-th smallest value."""
    ordered = np.sort(values[np.isfinite(values)])
    width = (ordered[-1] - ordered[0]) / bins
    for p, value in zip(percentiles, found):
        kth = ordered[int(np.ceil(p / 100 * ordered.size)) - 1]
        assert value - width - 1e-9 <= kth <= value + 1e-9, (p, value, kth, width)


def _check_outputs(out, names, stem):
    """Every frame's files, the range file and the mp4: one colour range, stored and used for every frame."""
    disparities = [np.load(out / f"{name}_disp.npy") for name in names]
    for name, disp in zip(names, disparities):
        np.testing.assert_array_equal(io.read_pfm(out / f"{name}_disp.pfm"), disp)
    stored = json.loads((out / f"{stem}_disp_range.json").read_text())
    vmin, vmax = read_colour_range(out / f"{stem}_disp.mp4")
    assert (vmin, vmax) == (stored["vmin"], stored["vmax"]) and stored["frames"] == len(names)
    # the pooled 1st and 99th percentiles of every frame's disparity, to the histogram's bin width
    _check_percentiles(np.concatenate([d.ravel() for d in disparities]), (vmin, vmax))
    video = read_frames(out / f"{stem}_disp.mp4")
    assert len(video) == len(names)
    for name, disp, frame in zip(names, disparities, video):
        coloured = colorize(disp, vmin=vmin, vmax=vmax)
        np.testing.assert_array_equal(io.read_image(out / f"{name}_disp.png"), coloured)
        assert frame.shape == coloured.shape
        assert np.abs(frame.astype(float) - coloured).mean() < 12  # H.264's loss, not another range
    return disparities


def test_video_pair_writes_every_frame_and_one_video_in_one_colour_range(clip, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["infer", "--video", str(clip / "L.mp4"), str(clip / "R.mp4"), "-o", str(out), *ITERS]) == 0
    assert f"wrote {FRAMES} disparity frames and L_disp.mp4" in capsys.readouterr().out
    names = [f"L_{t:06d}" for t in range(FRAMES)]
    disparities = _check_outputs(out, names, "L")
    # the stream's disparities of the decoded frames: frame t warm-started from frame t - 1
    expected = _streamed(read_frames(clip / "L.mp4"), read_frames(clip / "R.mp4"))
    for disp, want in zip(disparities, expected):
        np.testing.assert_array_equal(disp, want)


def test_side_by_side_video_is_split_in_halves(clip, tmp_path):
    out = tmp_path / "sbs"
    assert main(["infer", "--sbs", str(clip / "S.mp4"), "-o", str(out), *ITERS]) == 0
    disparities = _check_outputs(out, [f"S_{t:06d}" for t in range(FRAMES)], "S")
    assert disparities[0].shape == SIZE


def test_image_sequence_runs_as_a_video(clip, tmp_path):
    out = tmp_path / "seq"
    assert main(["infer", "--sequence", "-l", str(clip / "left" / "*.png"), "-r", str(clip / "right" / "*.png"),
                 "-o", str(out), "--fps", "5", *ITERS]) == 0
    names = [f"f{t:03d}" for t in range(FRAMES)]
    disparities = _check_outputs(out, names, "left")
    expected = _streamed([io.read_image(clip / "left" / f"{n}.png") for n in names],
                         [io.read_image(clip / "right" / f"{n}.png") for n in names])
    for disp, want in zip(disparities, expected):
        np.testing.assert_array_equal(disp, want)
    assert json.loads((out / "left_disp_range.json").read_text())["fps"] == 5.0


def _error(args, capsys) -> str:
    assert main(["infer", *args, *ITERS]) == 2
    return capsys.readouterr().err


def test_bad_input_is_one_clear_error_before_any_work(clip, tmp_path, capsys):
    frames = read_frames(clip / "L.mp4")
    _write_video(tmp_path / "short.mp4", frames[:4])
    _write_video(tmp_path / "small.mp4", [f[:, :64] for f in frames])
    _write_video(tmp_path / "odd.mp4", [np.pad(f, ((0, 0), (0, 1), (0, 0)), mode="edge") for f in frames],
                 pix_fmt="yuv444p")
    (tmp_path / "garbage.mp4").write_bytes(b"this is not a video" * 10)
    out = ["-o", str(tmp_path / "out")]
    message = _error(["--video", str(clip / "L.mp4"), str(tmp_path / "short.mp4"), *out], capsys)
    assert f"has {FRAMES} frames but" in message and "short.mp4 has 4" in message
    message = _error(["--video", str(clip / "L.mp4"), str(tmp_path / "small.mp4"), *out], capsys)
    assert "64x96" in message and "64x64" in message and "one size" in message
    assert "garbage.mp4: not a readable video" in _error(["--sbs", str(tmp_path / "garbage.mp4"), *out], capsys)
    assert "missing.mp4" in _error(["--sbs", str(tmp_path / "missing.mp4"), *out], capsys)
    assert "even width" in _error(["--sbs", str(tmp_path / "odd.mp4"), *out], capsys)
    assert "leave out -l" in _error(["--sbs", str(clip / "S.mp4"), "-l", "x.png", *out], capsys)
    assert "--calib" in _error(["--sbs", str(clip / "S.mp4"), "--calib", "rig.yml", *out], capsys)
    message = _error(["--sequence", "-l", str(clip / "left" / "*.png"), "-r", str(clip / "right" / "f00[0-2].png"),
                      *out], capsys)
    assert "6 left images" in message and "3 right images" in message
    assert not (tmp_path / "out").exists()  # nothing was written


def test_a_sequence_of_images_of_changing_size_stops_naming_the_file(tmp_path, capsys):
    require("av")
    for side in ("l", "r"):
        (tmp_path / side).mkdir()
        for t, size in enumerate((SIZE, SIZE, (48, 64))):
            io.write_image(tmp_path / side / f"{t}.png", np.zeros(size + (3,), np.uint8))
    message = _error(["--sequence", "-l", str(tmp_path / "l" / "*.png"), "-r", str(tmp_path / "r" / "*.png"),
                      "-o", str(tmp_path / "out")], capsys)
    assert "2.png is 48x64" in message and "first frame is 64x96" in message


def test_pooled_percentiles_are_the_percentiles_of_all_values_to_the_bin_width():
    rng = np.random.default_rng(0)
    arrays = [rng.gamma(2.0, 8.0, (20, 30)) for _ in range(5)]
    arrays[2][0, 0] = np.inf  # non-finite values are left out
    found = pooled_percentiles(lambda: iter(arrays), percentiles=(1, 99))
    _check_percentiles(np.concatenate([a.ravel() for a in arrays]), found)
    assert pooled_percentiles(lambda: iter([np.full((3, 3), 2.5)])) == (2.5, 2.5)


def test_a_disparity_video_of_odd_size_is_padded_and_a_failed_one_is_not_left_behind(tmp_path):
    require("av")
    disparities = [np.linspace(0, 40, 33 * 47).reshape(33, 47) + t for t in range(3)]
    with DisparityVideo(tmp_path / "odd.mp4", 12.5, (33, 47), 2.0, 38.0) as video:
        for disp in disparities:
            video.write(disp)
    frames = read_frames(tmp_path / "odd.mp4")
    assert len(frames) == 3 and frames[0].shape == (34, 48, 3)
    assert read_colour_range(tmp_path / "odd.mp4") == (2.0, 38.0)
    coloured = colorize(disparities[1], vmin=2.0, vmax=38.0)
    assert np.abs(frames[1][:33, :47].astype(float) - coloured).mean() < 12
    with pytest.raises(ShapeError, match="33x47"):
        with DisparityVideo(tmp_path / "bad.mp4", 10, (33, 47), 0.0, 1.0) as video:
            video.write(disparities[0])
            video.write(np.zeros((20, 20)))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["odd.mp4"]  # no file, no temporary file
