"""Fuzzing every file reader: PFM, KITTI / CREStereo PNG, images, calib.txt / K.txt, .npy, safetensors
and MIPNet weights. Any input is read correctly or raises the reader's documented exception; lying
headers are rejected before anything is allocated; valid files round-trip exactly.

The seed corpus is generated here, from the writers, as small valid files and broken variants.
"""

from __future__ import annotations

import contextlib
import io as pyio
import json
import re
import struct
import zlib

import numpy as np
import pytest

from helpers import require

require("hypothesis")
from hypothesis import given, strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

import mipnet  # noqa: E402
from mipnet.stereo import io  # noqa: E402
from mipnet.errors import FormatError  # noqa: E402
from mipnet.serialization import load_safetensors, save_safetensors  # noqa: E402
from fuzzing import (NASTY_FLOATS, NASTY_INTS, allocation_peak, as_file, assert_reads_or_raises,  # noqa: E402
                     fuzz_settings, le_u64, mutations, written_bytes)

# ----------------------------------------------------------------------------------- the seed corpus


def _pil_bytes(array: np.ndarray, fmt: str, mode: str | None = None, **options) -> bytes:
    from PIL import Image

    buffer = pyio.BytesIO()
    image = Image.fromarray(array) if mode is None else Image.fromarray(array).convert(mode)
    image.save(buffer, format=fmt, **options)
    return buffer.getvalue()


_RNG = np.random.default_rng(0)
_RGB = _RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)
_DISP = np.round(_RNG.uniform(0, 60, (4, 6)) * 256) / 256

PFM_SEEDS = [
    written_bytes(io.write_pfm, _RNG.standard_normal((3, 4)).astype(np.float32)),
    written_bytes(io.write_pfm, _RNG.standard_normal((2, 3, 3)).astype(np.float32)),
    b"Pf\n2 1\n1.0\n" + np.array([1.5, np.inf], ">f4").tobytes(),  # big-endian, Middlebury's inf
    b"Pf\n4 4\n-1\n" + bytes(20),  # truncated data
    b"Pf\n1000000 1000000\n-1\n" + bytes(16),  # a header claiming 10^12 floats
]
KITTI_SEEDS = [
    written_bytes(io.write_kitti_disparity, _DISP, suffix=".png"),
    written_bytes(io.write_crestereo_disparity, _DISP, suffix=".png"),
    _pil_bytes(_RGB[:, :, 0], "PNG"),  # 8-bit: not a disparity map
]
IMAGE_SEEDS = [
    _pil_bytes(_RGB, "PNG"),
    _pil_bytes(_RGB, "PNG", "P"),
    _pil_bytes(_RGB, "PNG", "LA"),
    _pil_bytes(_RGB, "JPEG", quality=90),
    _pil_bytes(_RGB, "JPEG", progressive=True),
    _pil_bytes(_RGB, "BMP"),
    _pil_bytes(_RGB, "PPM"),
    _pil_bytes(_RGB[:, :, 0], "PPM"),
    _pil_bytes(_RGB, "TIFF", compression="tiff_deflate"),
    _pil_bytes(_RGB, "GIF"),
    _pil_bytes(_RGB, "WEBP", lossless=True),
    KITTI_SEEDS[0],  # 16-bit gray
]
CALIB_SEEDS = [
    b"cam0=[1758.23 0 953.34; 0 1758.23 552.29; 0 0 1]\ncam1=[1758.23 0 953.34; 0 1758.23 552.29; 0 0 1]\n"
    b"doffs=0\nbaseline=111.53\nwidth=1920\nheight=1080\nndisp=290\nisint=0\nvmin=75\nvmax=262\n",
    b"cam0=[541.764 0 553.869; 0 541.764 232.396; 0 0 1]\ncam1=[541.764 0 553.869; 0 541.764 232.396; 0 0 1]\n"
    b"baseline=60.0\nwidth=942\nheight=489\n",  # ETH3D: no doffs, ndisp
    b"754.668 0.0 489.379 0.0 754.668 265.162 0.0 0.0 1.0\n0.063\n",  # FoundationStereo K.txt
    b"cam0=[1 0 0; 0 1 0]\nbaseline=1\n",  # a 2x3 matrix
]
NPY_SEEDS = [
    written_bytes(lambda p, a: np.save(p, a), _DISP.astype(np.float32), suffix=".npy"),
    written_bytes(lambda p, a: np.save(p, a), np.asfortranarray(_DISP), suffix=".npy"),
]


def _safetensors_bytes(header: dict, body: bytes, length: int | None = None) -> bytes:
    head = json.dumps(header).encode()
    return le_u64(len(head) if length is None else length) + head + body


SAFETENSORS_SEEDS = [
    written_bytes(save_safetensors, {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "b": np.array([1, 2], np.int64),
                                "c": np.zeros((0, 4), np.float16)}, {"note": "seed"}, suffix=".safetensors"),
    _safetensors_bytes({"x": {"dtype": "F32", "shape": [10**12], "data_offsets": [0, 4 * 10**12]}}, bytes(16)),
]


def _weights_seed() -> bytes:
    """MIPNet weights of a small valid config stripped to two tensors, so mutations reach the config
    and state-dict checks of mipnet.load."""
    model = mipnet.MIPNet()
    tensors = dict(list(model.state_dict().items())[:2])
    return written_bytes(save_safetensors, tensors, {"format": "mipnet", "config": model.config.to_json()},
                    suffix=".safetensors")


WEIGHTS_SEEDS = [_weights_seed()]

# -------------------------------------------------------------------------- checks of a successful read


def _check_pfm(image) -> None:
    assert image.dtype == np.float32 and (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3))


def _check_disparity(result) -> None:
    disparity, valid = result
    assert disparity.dtype == np.float32 and valid.dtype == bool and disparity.shape == valid.shape
    assert disparity.ndim == 2 and np.all(disparity[valid] > 0) and np.all(disparity[~valid] == 0)


def _check_image(image) -> None:
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3 and image.flags.c_contiguous


def _check_calib(calib) -> None:
    for key in ("fx", "fy", "cx", "cy", "doffs", "baseline"):
        assert np.isfinite(calib[key]), key
    assert calib["fx"] > 0 and calib["fy"] > 0 and calib["baseline"] > 0


def _check_tensors(result) -> None:
    tensors, meta = result
    assert all(isinstance(a, np.ndarray) for a in tensors.values())
    assert all(isinstance(k, str) and isinstance(v, str) for k, v in meta.items())


# ------------------------------------------------------------------------------------ mutation fuzzing

READERS = {
    "pfm": (io.read_pfm, PFM_SEEDS, _check_pfm),
    "kitti_png": (io.read_kitti_disparity, KITTI_SEEDS, _check_disparity),
    "crestereo_png": (io.read_crestereo_disparity, KITTI_SEEDS, _check_disparity),
    "image": (io.read_image, IMAGE_SEEDS, _check_image),
    "calib": (io.read_calib, CALIB_SEEDS, _check_calib),
    "npy": (io.read_npy, NPY_SEEDS, lambda a: isinstance(a, np.ndarray)),
    "safetensors": (load_safetensors, SAFETENSORS_SEEDS, _check_tensors),
}
#: Examples per reader (mutation fuzzing); the structured strategies below add their own.
MUTATION_EXAMPLES = {"pfm": 300, "kitti_png": 200, "crestereo_png": 100, "image": 400, "calib": 300, "npy": 200,
                     "safetensors": 300}


#: Image readers run with Pillow's pixel limit lowered to this, so that what a small file with a lying
#: header can make them allocate (bounded by the limit, not by the file) fits the harness's bound.
FUZZ_PIXEL_LIMIT = 2**20
IMAGE_READERS = ("kitti_png", "crestereo_png", "image")


@contextlib.contextmanager
def pixel_limit(pixels: int):
    """Pillow's decompression-bomb limit set to ``pixels`` inside the block."""
    from PIL import Image

    previous, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, pixels
    try:
        yield
    finally:
        Image.MAX_IMAGE_PIXELS = previous


def _mutation_test(name: str):
    reader, seeds, check = READERS[name]

    @fuzz_settings(MUTATION_EXAMPLES[name])
    @given(data=mutations(seeds))
    def test(data):
        with pixel_limit(FUZZ_PIXEL_LIMIT) if name in IMAGE_READERS else contextlib.nullcontext():
            assert_reads_or_raises(reader, data, allowed=(FormatError,), check=check)

    return test


test_pfm_mutations = _mutation_test("pfm")
test_kitti_png_mutations = _mutation_test("kitti_png")
test_crestereo_png_mutations = _mutation_test("crestereo_png")
test_image_mutations = _mutation_test("image")
test_calib_mutations = _mutation_test("calib")
test_npy_mutations = _mutation_test("npy")
test_safetensors_mutations = _mutation_test("safetensors")


@fuzz_settings(60)
@given(data=mutations(WEIGHTS_SEEDS, raw_max_size=64))
def test_weights_loader_survives_mutated_files(data):
    """mipnet.load adds the config and state-dict checks on top of the safetensors reader."""
    assert_reads_or_raises(mipnet.load, data, allowed=(FormatError,), check=lambda m: isinstance(m, mipnet.MIPNet))


# ------------------------------------------------------------------------- structure-aware generation

_header_int = st.one_of(st.integers(-2, 40), st.sampled_from(NASTY_INTS))
_header_float = st.one_of(st.sampled_from(NASTY_FLOATS), st.floats(allow_nan=True).map(repr))


@st.composite
def pfm_files(draw) -> bytes:
    """A PFM header with drawn magic, size and scale (often lying) and a drawn amount of data."""
    magic = draw(st.sampled_from([b"Pf", b"PF", b"pf", b"P6", b"Pf "]))
    width, height = draw(_header_int), draw(_header_int)
    size = draw(st.sampled_from([f"{width} {height}", f"{width}", f"{width} {height} 7", "x y", ""]))
    scale = draw(_header_float)
    channels = 3 if magic == b"PF" else 1
    promised = 4 * width * height * channels if 0 < width <= 64 and 0 < height <= 64 else 0
    length = draw(st.sampled_from([promised, max(promised - 1, 0), promised + 3, 0]))
    sep = draw(st.sampled_from([b"\n", b"\r\n", b" "]))
    return magic + sep + size.encode() + sep + scale.encode() + sep + draw(st.binary(min_size=length, max_size=length))


@fuzz_settings(300)
@given(data=pfm_files())
def test_pfm_reader_survives_generated_headers(data):
    assert_reads_or_raises(io.read_pfm, data, allowed=(FormatError,), check=_check_pfm)


_matrix = st.lists(_header_float, min_size=0, max_size=11).map(lambda v: "[" + " ".join(v) + "]")
_calib_value = st.one_of(_matrix, _header_float, _header_int.map(str), st.text(max_size=12))
_calib_key = st.sampled_from(["cam0", "cam1", "doffs", "baseline", "width", "height", "ndisp", "vmin", "vmax", "junk"])


@st.composite
def calib_files(draw) -> bytes:
    """calib.txt (``key=value`` lines) or K.txt (lines of numbers) with drawn keys, values and counts."""
    if draw(st.booleans()):
        lines = draw(st.lists(st.tuples(_calib_key, _calib_value).map(lambda kv: f"{kv[0]}={kv[1]}"), max_size=10))
    else:
        lines = draw(st.lists(st.lists(_header_float, max_size=10).map(" ".join), max_size=3))
    return "\n".join(lines).encode("utf-8", "surrogatepass")


@fuzz_settings(300)
@given(data=calib_files())
def test_calib_reader_survives_generated_files(data):
    assert_reads_or_raises(io.read_calib, data, allowed=(FormatError,), check=_check_calib)


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.sampled_from(NASTY_INTS) | st.text(max_size=8),
                     lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
                     max_leaves=12)
_entry = st.fixed_dictionaries(
    {"dtype": st.one_of(st.sampled_from(["F32", "F64", "F16", "I64", "I32", "I16", "I8", "U8", "BOOL", "F8", "f32"]), _json),
     "shape": st.one_of(st.lists(_header_int, max_size=4), _json),
     "data_offsets": st.one_of(st.lists(_header_int, min_size=2, max_size=2), _json)})


@st.composite
def safetensors_files(draw) -> bytes:
    """A safetensors file whose JSON header has drawn entries (often inconsistent with the body), an
    optional __metadata__, a drawn body length and sometimes a lying header length."""
    header = draw(st.dictionaries(st.text(max_size=6), st.one_of(_entry, _json), max_size=4))
    if draw(st.booleans()):
        header["__metadata__"] = draw(st.one_of(st.dictionaries(st.text(max_size=4), st.text(max_size=4)), _json))
    body = draw(st.binary(max_size=64))
    head = json.dumps(header).encode()
    length = draw(st.one_of(st.just(len(head)), st.sampled_from([v for v in NASTY_INTS if 0 <= v < 2**64])))
    return le_u64(length) + head + body


@fuzz_settings(300)
@given(data=safetensors_files())
def test_safetensors_reader_survives_generated_headers(data):
    assert_reads_or_raises(load_safetensors, data, allowed=(FormatError,), check=_check_tensors)


_MODES = ["1", "L", "LA", "P", "RGB", "RGBA", "CMYK", "YCbCr", "I", "I;16", "F", "LAB", "HSV"]
_FORMATS = {"PNG": ".png", "TIFF": ".tif", "BMP": ".bmp", "PPM": ".ppm", "JPEG": ".jpg", "WEBP": ".webp", "GIF": ".gif"}


@st.composite
def pillow_images(draw) -> bytes:
    """An image of a drawn Pillow mode, size and format (combinations Pillow cannot save are skipped)."""
    from PIL import Image

    mode, fmt = draw(st.sampled_from(_MODES)), draw(st.sampled_from(sorted(_FORMATS)))
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    pixels = draw(hnp.arrays(np.uint8, (h, w, 3)))
    image = Image.fromarray(pixels).convert(mode) if mode not in ("LAB", "HSV") else Image.new(mode, (w, h))
    buffer = pyio.BytesIO()
    try:
        image.save(buffer, format=fmt)
    except (OSError, ValueError, KeyError):
        return _pil_bytes(pixels, "PNG")
    return buffer.getvalue()


@fuzz_settings(200)
@given(data=pillow_images())
def test_image_reader_reads_every_mode_or_raises_format_error(data):
    image = assert_reads_or_raises(io.read_image, data, allowed=(FormatError,), check=_check_image)
    from PIL import Image

    mode = Image.open(pyio.BytesIO(data)).mode
    if mode == "F":
        assert image is None, "a floating-point image is not a colour image"
    elif mode != "LAB":  # Pillow converts LAB to RGB for some formats only
        assert image is not None, f"a {mode} image was not read"


# --------------------------------------------------------------------------- lying headers, explicitly

def _png_with_size(width: int, height: int) -> bytes:
    """A valid 1x1 16-bit PNG whose IHDR is rewritten to claim ``width`` x ``height`` (CRC fixed)."""
    png = bytearray(KITTI_SEEDS[0])
    # IHDR data starts after the 8-byte signature, the 4-byte length and the 4-byte type
    png[16:24] = struct.pack(">II", width, height)
    # the CRC covers the chunk type and data: bytes 12..29, stored at 29..33
    png[29:33] = struct.pack(">I", zlib.crc32(bytes(png[12:29])))
    return bytes(png)


def _npy_claiming(shape: tuple) -> bytes:
    """A .npy header of float32 ``shape`` followed by 16 bytes of data."""
    buffer = pyio.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": "<f4", "fortran_order": False, "shape": shape})
    return buffer.getvalue() + bytes(16)


@pytest.mark.parametrize("reader, data, sizes", [
    (io.read_pfm, b"Pf\n1000000 1000000\n-1\n" + bytes(64), "1000000x1000000x1"),
    (io.read_pfm, b"PF\n4 4\n-1\n" + bytes(4 * 16), "4x4x3"),
    (load_safetensors, SAFETENSORS_SEEDS[1], "[1000000000000]"),
    (load_safetensors, _safetensors_bytes({"x": {"dtype": "F32", "shape": [2**32, 2**32], "data_offsets": [0, 0]}}, b""),
     "[4294967296, 4294967296]"),  # the element count overflows int64
    (load_safetensors, le_u64(10**12) + b"{}", "1000000000000"),
    (io.read_npy, _npy_claiming((10**12,)), "[1000000000000]"),
    (io.read_image, _png_with_size(60000, 60000), "3600000000 pixels"),
    (io.read_kitti_disparity, _png_with_size(9000, 9000), "9000x9000"),
], ids=["pfm", "pfm-colour", "safetensors", "safetensors-int64-overflow", "safetensors-header-length", "npy",
        "png-over-pixel-limit", "png-beyond-deflate"])
def test_a_lying_header_is_rejected_before_allocating(reader, data, sizes):
    """A header claiming far more data than the file holds raises FormatError naming the file and the
    claimed size, after allocating less than 1 MiB."""
    with as_file(data) as path, allocation_peak() as alloc:
        with pytest.raises(FormatError, match=re.escape(sizes)) as error:
            reader(path)
    assert path in str(error.value)
    assert alloc["peak"] < 2**20, f"allocated {alloc['peak']} bytes"


# ------------------------------------------------------------------------------ valid files round-trip

@fuzz_settings(100)
@given(image=hnp.arrays(np.float32, st.one_of(hnp.array_shapes(min_dims=2, max_dims=2, max_side=9),
                                               st.tuples(st.integers(1, 9), st.integers(1, 9), st.just(3)))))
def test_pfm_round_trips_every_float32_array(image):
    data = written_bytes(io.write_pfm, image, suffix=".pfm")
    read = assert_reads_or_raises(io.read_pfm, data, allowed=())
    np.testing.assert_array_equal(read, image)


@fuzz_settings(100)
@given(disparity=hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, max_side=9),
                            elements=st.floats(0, 255.99, allow_nan=False)),
       reader_writer=st.sampled_from([(io.read_kitti_disparity, io.write_kitti_disparity, 256),
                                      (io.read_crestereo_disparity, io.write_crestereo_disparity, 32)]))
def test_disparity_png_round_trips_to_the_nearest_step(disparity, reader_writer):
    reader, writer, scale = reader_writer
    read, valid = assert_reads_or_raises(reader, written_bytes(writer, disparity, suffix=".png"), allowed=())
    np.testing.assert_array_equal(valid, disparity > 0)
    # the documented quantisation: the nearest 1/scale step, at least one step so valid pixels stay valid
    expected = np.clip(np.rint(disparity * scale), 1, 65535) / scale
    np.testing.assert_array_equal(read[valid], expected[valid].astype(np.float32))


@fuzz_settings(100)
@given(image=hnp.arrays(np.uint8, st.tuples(st.integers(1, 9), st.integers(1, 9), st.sampled_from([1, 3, 4]))),
       suffix=st.sampled_from([".png", ".bmp", ".tif", ".ppm"]))
def test_lossless_images_round_trip(image, suffix):
    if suffix in (".bmp", ".ppm") and image.shape[2] == 4:
        image = image[:, :, :3]  # these formats keep no alpha
    read = assert_reads_or_raises(io.read_image, written_bytes(io.write_image, image, suffix=suffix), allowed=())
    expected = np.repeat(image, 3, axis=2) if image.shape[2] == 1 else image[:, :, :3]
    np.testing.assert_array_equal(read, expected)


_finite = st.floats(-1e6, 1e6, allow_nan=False)
_positive = st.floats(1e-3, 1e6)


@fuzz_settings(100)
@given(fx=_positive, cx=_finite, cy=_finite, baseline=_positive, doffs=_finite, k_txt=st.booleans())
def test_calibrations_round_trip(fx, cx, cy, baseline, doffs, k_txt):
    if k_txt:
        text = f"{fx!r} 0 {cx!r} 0 {fx!r} {cy!r} 0 0 1\n{baseline!r}\n"
    else:
        text = f"cam0=[{fx!r} 0 {cx!r}; 0 {fx!r} {cy!r}; 0 0 1]\ndoffs={doffs!r}\nbaseline={baseline!r}\n"
    calib = assert_reads_or_raises(io.read_calib, text.encode(), allowed=())
    expected = {"fx": fx, "fy": fx, "cx": cx, "cy": cy, "doffs": 0.0 if k_txt else doffs, "baseline": baseline}
    assert {k: calib[k] for k in expected} == expected
    assert calib["baseline_unit"] == ("m" if k_txt else "mm")


_dtypes = st.sampled_from([np.float32, np.float64, np.float16, np.int64, np.int32, np.int16, np.int8, np.uint8, np.bool_])


@fuzz_settings(100)
@given(tensors=st.dictionaries(st.text(min_size=1, max_size=8).filter(lambda k: k != "__metadata__"),
                               _dtypes.flatmap(lambda d: hnp.arrays(d, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4))),
                               max_size=4),
       metadata=st.dictionaries(st.text(max_size=8), st.text(max_size=8), max_size=3))
def test_safetensors_round_trip(tensors, metadata):
    read, meta = assert_reads_or_raises(load_safetensors, written_bytes(save_safetensors, tensors, metadata), allowed=())
    assert read.keys() == tensors.keys() and meta == metadata
    for name, array in tensors.items():
        assert read[name].dtype == array.dtype and read[name].shape == array.shape
        np.testing.assert_array_equal(read[name], array)


@fuzz_settings(50)
@given(array=_dtypes.flatmap(lambda d: hnp.arrays(d, hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5))),
       fortran=st.booleans())
def test_npy_round_trips(array, fortran):
    array = np.asfortranarray(array) if fortran else array
    read = assert_reads_or_raises(io.read_npy, written_bytes(lambda p, a: np.save(p, a), array, suffix=".npy"), allowed=())
    assert read.dtype == array.dtype and read.shape == array.shape
    np.testing.assert_array_equal(read, array)
