"""mipnet.stereo.io: every writer round-trips through its reader; bad files raise FormatError naming the
file; writers are atomic."""

import os
import struct

import numpy as np
import pytest
from mipnet.utils import files as _fileutil
from mipnet.errors import FormatError, MipnetError
from mipnet.stereo.io import (
    read_calib,
    read_crestereo_disparity,
    read_image,
    read_kitti_disparity,
    read_pfm,
    write_crestereo_disparity,
    write_image,
    write_kitti_disparity,
    write_pfm,
    write_ply,
)
from PIL import Image


def _raw_pfm(path, data: bytes, magic=b"Pf", size=b"3 2", scale=b"-1"):
    path.write_bytes(magic + b"\n" + size + b"\n" + scale + b"\n" + data)
    return path


# ------------------------------------------------------------------------------------- PFM


def test_pfm_round_trip_one_channel_keeps_inf_and_nan(tmp_path):
    disp = np.arange(12, dtype=np.float32).reshape(3, 4) * 1.5
    disp[0, 1] = np.inf
    disp[2, 3] = np.nan
    write_pfm(tmp_path / "d.pfm", disp)
    back = read_pfm(tmp_path / "d.pfm")
    assert back.dtype == np.float32 and back.shape == (3, 4)
    np.testing.assert_array_equal(back, disp)  # nan == nan for assert_array_equal
    assert np.isposinf(back[0, 1])


def test_pfm_round_trip_three_channels(tmp_path):
    image = np.random.default_rng(0).normal(size=(2, 5, 3)).astype(np.float32)
    image[1, 2, 0] = -np.inf
    write_pfm(tmp_path / "c.pfm", image)
    back = read_pfm(tmp_path / "c.pfm")
    assert back.shape == (2, 5, 3)
    np.testing.assert_array_equal(back, image)
    assert (tmp_path / "c.pfm").read_bytes().startswith(b"PF\n5 2\n-1\n")


def test_pfm_writer_header_and_bottom_up_little_endian_rows(tmp_path):
    disp = np.array([[1, 2, 3], [4, 5, 6]], dtype=np.float32)
    write_pfm(tmp_path / "d.pfm", disp)
    raw = (tmp_path / "d.pfm").read_bytes()
    header = b"Pf\n3 2\n-1\n"
    assert raw[: len(header)] == header
    values = struct.unpack("<6f", raw[len(header):])
    assert values == (4, 5, 6, 1, 2, 3)  # bottom row first


@pytest.mark.parametrize("scale, fmt", [(b"-1.0", "<"), (b"1.0", ">"), (b"-0.5", "<"), (b"2", ">")])
def test_pfm_reads_both_endiannesses(tmp_path, scale, fmt):
    expected = np.array([[1.5, -2.0, np.inf], [0.25, 1e6, -3.0]], dtype=np.float32)
    data = struct.pack(f"{fmt}6f", *expected[::-1].ravel())
    back = read_pfm(_raw_pfm(tmp_path / "x.pfm", data, scale=scale))
    np.testing.assert_array_equal(back, expected)
    assert back.dtype.byteorder in ("=", "|", "<" if np.little_endian else ">")


@pytest.mark.parametrize(
    "kwargs, data_len, message",
    [
        ({"magic": b"P6"}, 24, "not a PFM"),
        ({"size": b"3"}, 24, "size"),
        ({"size": b"three 2"}, 24, "size"),
        ({"size": b"0 2"}, 24, "size"),
        ({"scale": b"abc"}, 24, "scale"),
        ({"scale": b"0"}, 24, "scale"),
        ({}, 23, "truncated"),
        ({}, 0, "truncated"),
    ],
)
def test_pfm_corrupt_files_raise_format_error_naming_the_file(tmp_path, kwargs, data_len, message):
    path = _raw_pfm(tmp_path / "broken.pfm", b"\0" * data_len, **kwargs)
    with pytest.raises(FormatError, match=message) as info:
        read_pfm(path)
    assert "broken.pfm" in str(info.value)
    assert isinstance(info.value, MipnetError) and isinstance(info.value, RuntimeError)


def test_pfm_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_pfm(tmp_path / "nope.pfm")


def test_write_pfm_rejects_bad_shapes(tmp_path):
    with pytest.raises(ValueError):
        write_pfm(tmp_path / "x.pfm", np.zeros((2, 2, 2)))
    assert not (tmp_path / "x.pfm").exists()


# --------------------------------------------------------------------- 16-bit disparity PNGs


def test_kitti_round_trip_and_encoding(tmp_path):
    disp = np.array([[0.0, 1.0, 2.5, 100.00390625], [np.nan, -3.0, np.inf, 7.1]], dtype=np.float32)
    write_kitti_disparity(tmp_path / "k.png", disp)
    raw = np.asarray(Image.open(tmp_path / "k.png"))
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(raw, [[0, 256, 640, 25601], [0, 0, 0, round(7.1 * 256)]])
    back, valid = read_kitti_disparity(tmp_path / "k.png")
    assert back.dtype == np.float32 and valid.dtype == bool
    np.testing.assert_array_equal(valid, [[False, True, True, True], [False, False, False, True]])
    np.testing.assert_allclose(back[valid], disp[valid], atol=0.5 / 256)
    assert np.all(back[~valid] == 0)


def test_kitti_writer_valid_mask_clipping_and_tiny_values(tmp_path):
    disp = np.array([[5.0, 5.0, 1000.0, 1e-4]], dtype=np.float32)
    write_kitti_disparity(tmp_path / "k.png", disp, valid=np.array([[True, False, True, True]]))
    back, valid = read_kitti_disparity(tmp_path / "k.png")
    np.testing.assert_array_equal(valid, [[True, False, True, True]])
    assert back[0, 2] == pytest.approx(65535 / 256)  # clipped to the uint16 range
    assert back[0, 3] == pytest.approx(1 / 256)  # a valid value never becomes "no ground truth"


def test_crestereo_round_trip(tmp_path):
    disp = np.array([[0.0, 1.0 / 32, 33.3], [2047.0, 5000.0, -1.0]], dtype=np.float32)
    write_crestereo_disparity(tmp_path / "a.disp.png", disp)
    raw = np.asarray(Image.open(tmp_path / "a.disp.png"))
    np.testing.assert_array_equal(raw, [[0, 1, round(33.3 * 32)], [2047 * 32, 65535, 0]])
    back, valid = read_crestereo_disparity(tmp_path / "a.disp.png")
    np.testing.assert_array_equal(valid, raw > 0)
    np.testing.assert_allclose(back[0, 2], 33.3, atol=0.5 / 32)


@pytest.mark.parametrize("reader", [read_kitti_disparity, read_crestereo_disparity])
def test_disparity_png_rejects_8bit_and_colour_images(tmp_path, reader):
    Image.fromarray(np.full((4, 4), 7, np.uint8)).save(tmp_path / "gray8.png")
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "rgb.png")
    for name in ("gray8.png", "rgb.png"):
        with pytest.raises(FormatError, match="16-bit") as info:
            reader(tmp_path / name)
        assert name in str(info.value)


@pytest.mark.parametrize("reader", [read_kitti_disparity, read_crestereo_disparity, read_image])
def test_image_readers_reject_garbage_and_truncated_files(tmp_path, reader):
    (tmp_path / "garbage.png").write_bytes(b"this is not a png at all")
    write_kitti_disparity(tmp_path / "full.png", np.random.default_rng(1).uniform(1, 50, (64, 64)))
    data = (tmp_path / "full.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    for name in ("garbage.png", "cut.png"):
        with pytest.raises(FormatError) as info:
            reader(tmp_path / name)
        assert name in str(info.value)


# ------------------------------------------------------------------------------------ images


def test_image_round_trip_png_and_jpeg(tmp_path):
    rgb = np.random.default_rng(2).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    write_image(tmp_path / "a.png", rgb)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), rgb)
    smooth = np.broadcast_to(np.linspace(0, 255, 16, dtype=np.uint8)[None, :, None], (16, 16, 3)).copy()
    write_image(tmp_path / "a.jpg", smooth, quality=95)
    back = read_image(tmp_path / "a.jpg")
    assert back.shape == (16, 16, 3) and back.dtype == np.uint8
    assert np.abs(back.astype(int) - smooth).mean() < 4


def test_read_image_converts_gray_alpha_palette_and_16bit(tmp_path):
    gray = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    write_image(tmp_path / "g.png", gray)
    np.testing.assert_array_equal(read_image(tmp_path / "g.png"), np.repeat(gray[:, :, None], 3, axis=2))

    rgba = np.random.default_rng(3).integers(0, 256, (3, 4, 4), dtype=np.uint8)
    write_image(tmp_path / "a.png", rgba)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), rgba[:, :, :3])

    Image.fromarray(np.full((2, 2, 3), [10, 20, 30], np.uint8)).quantize(4).save(tmp_path / "p.png")
    np.testing.assert_array_equal(read_image(tmp_path / "p.png")[0, 0], [10, 20, 30])

    sixteen = np.array([[0, 257, 65535, 1000]], dtype=np.uint16)
    Image.fromarray(sixteen).save(tmp_path / "s.png")
    np.testing.assert_array_equal(read_image(tmp_path / "s.png")[0, :, 0], [0, 1, 255, 4])


def test_write_image_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError):
        write_image(tmp_path / "a.png", np.zeros((2, 2), np.float32))
    with pytest.raises(ValueError):
        write_image(tmp_path / "a.unknownext", np.zeros((2, 2), np.uint8))


# ------------------------------------------------------------------------------- calibration

MIDDLEBURY_CALIB = """cam0=[4161.221 0 1445.577; 0 4161.221 984.686; 0 0 1]
cam1=[4161.221 0 1654.636; 0 4161.221 984.686; 0 0 1]
doffs=209.059
baseline=176.252
width=2880
height=1988
ndisp=280
isint=0
vmin=33
vmax=218
dyavg=0
dymax=0
"""


def test_read_calib_middlebury(tmp_path):
    (tmp_path / "calib.txt").write_text(MIDDLEBURY_CALIB)
    calib = read_calib(tmp_path / "calib.txt")
    assert calib["fx"] == pytest.approx(4161.221) and calib["fy"] == pytest.approx(4161.221)
    assert calib["cx"] == pytest.approx(1445.577) and calib["cy"] == pytest.approx(984.686)
    assert calib["doffs"] == pytest.approx(209.059)
    assert calib["baseline"] == pytest.approx(176.252) and calib["baseline_unit"] == "mm"
    assert (calib["width"], calib["height"], calib["ndisp"]) == (2880, 1988, 280)
    assert calib["vmin"] == 33 and calib["vmax"] == 218


def test_read_calib_doffs_from_cam1_when_missing(tmp_path):
    text = "\n".join(line for line in MIDDLEBURY_CALIB.splitlines() if not line.startswith("doffs"))
    (tmp_path / "calib.txt").write_text(text)
    assert read_calib(tmp_path / "calib.txt")["doffs"] == pytest.approx(1654.636 - 1445.577)


def test_read_calib_k_txt(tmp_path):
    (tmp_path / "K.txt").write_text("700.5 0 640.25 0 701.5 360.75 0 0 1\n0.12\n")
    calib = read_calib(tmp_path / "K.txt")
    assert calib == {"fx": 700.5, "fy": 701.5, "cx": 640.25, "cy": 360.75, "doffs": 0.0,
                     "baseline": 0.12, "baseline_unit": "m"}


@pytest.mark.parametrize(
    "text",
    [
        "cam0=[1 0 2; 0 1 3]\nbaseline=10\n",  # 6 numbers
        "cam0=[1 0 2; 0 1 3; 0 0 1]\n",  # no baseline
        "cam0=[1 0 2; 0 1 3; 0 0 1]\nbaseline=ten\n",
        "cam0=[1 0 2; 0 1 3; 0 0 1]\nbaseline=10\nndisp=12.5\n",
        "1 0 2 0 1 3 0 0 1\n",  # K.txt without baseline
        "1 0 2 0 1 3 0 0\n0.1\n",  # 8 intrinsics
        "1 0 2 0 x 3 0 0 1\n0.1\n",
    ],
)
def test_read_calib_corrupt_raises_naming_the_file(tmp_path, text):
    (tmp_path / "bad_calib.txt").write_text(text)
    with pytest.raises(FormatError) as info:
        read_calib(tmp_path / "bad_calib.txt")
    assert "bad_calib.txt" in str(info.value)


# ------------------------------------------------------------------------------------- PLY


def _parse_ply(path):
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:end].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    count = int(header[2].split()[2])
    props = [line.split() for line in header if line.startswith("property")]
    dtype = [(name, {"float": "<f4", "uchar": "u1"}[kind]) for _, kind, name in props]
    return np.frombuffer(raw[end:], dtype=dtype, count=count), len(raw) - end


def test_ply_round_trip_with_and_without_colours(tmp_path):
    points = np.array([[0, 1, 2], [-1.5, 2.25, 1e3]], dtype=np.float32)
    colors = np.array([[255, 0, 10], [1, 2, 3]], dtype=np.uint8)
    write_ply(tmp_path / "c.ply", points, colors)
    vertices, nbytes = _parse_ply(tmp_path / "c.ply")
    assert nbytes == 2 * 15
    np.testing.assert_array_equal(np.stack([vertices[k] for k in "xyz"], 1), points)
    np.testing.assert_array_equal(np.stack([vertices[k] for k in ("red", "green", "blue")], 1), colors)

    write_ply(tmp_path / "p.ply", points)
    vertices, nbytes = _parse_ply(tmp_path / "p.ply")
    assert vertices.dtype.names == ("x", "y", "z") and nbytes == 24

    write_ply(tmp_path / "empty.ply", np.zeros((0, 3)), np.zeros((0, 3), np.uint8))
    assert len(_parse_ply(tmp_path / "empty.ply")[0]) == 0


def test_ply_rejects_mismatched_colours(tmp_path):
    with pytest.raises(ValueError):
        write_ply(tmp_path / "x.ply", np.zeros((3, 3)), np.zeros((2, 3), np.uint8))


# ---------------------------------------------------------------------------- atomic writes

_WRITERS = {
    "pfm": lambda p: write_pfm(p, np.ones((4, 4))),
    "kitti": lambda p: write_kitti_disparity(p, np.ones((4, 4))),
    "crestereo": lambda p: write_crestereo_disparity(p, np.ones((4, 4))),
    "image": lambda p: write_image(p, np.zeros((4, 4, 3), np.uint8)),
    "ply": lambda p: write_ply(p, np.zeros((4, 3)), np.zeros((4, 3), np.uint8)),
}


@pytest.mark.parametrize("writer", sorted(_WRITERS))
@pytest.mark.parametrize("existing", [False, True])
def test_writers_are_atomic_when_failing_mid_write(tmp_path, monkeypatch, writer, existing):
    target = tmp_path / "out.png"
    if existing:
        target.write_bytes(b"old content")

    def failing_fsync(fd):
        assert os.fstat(fd).st_size > 0  # the data was already being written
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(_fileutil.os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="simulated"):
        _WRITERS[writer](target)
    assert sorted(os.listdir(tmp_path)) == (["out.png"] if existing else [])
    if existing:
        assert target.read_bytes() == b"old content"


def test_atomic_write_success_and_failure_inside_block(tmp_path):
    target = tmp_path / "f.txt"
    with _fileutil.atomic_write(target, "w") as f:
        f.write("hello")
        assert not target.exists()
    assert target.read_text() == "hello"
    assert target.stat().st_mode & 0o777 == 0o666 & ~_fileutil._UMASK  # not mkstemp's 0600
    with pytest.raises(RuntimeError):
        with _fileutil.atomic_write(target, "w") as f:
            f.write("partial")
            raise RuntimeError("boom")
    assert target.read_text() == "hello"
    assert os.listdir(tmp_path) == ["f.txt"]
