"""Readers and writers for the files stereo users meet: PFM, KITTI and CREStereo disparity PNGs,
RGB images, Middlebury/ETH3D ``calib.txt`` and FoundationStereo ``K.txt`` calibrations, and binary PLY.

Every reader raises :class:`mipnet.errors.FormatError` (naming the file) when a file is corrupt,
truncated or not in the expected format; a file that cannot be opened raises the usual ``OSError``
(``FileNotFoundError``, ``IsADirectoryError``, ``PermissionError``). A header claiming more data than
the file holds is rejected before anything is allocated (PFM, ``.npy``; PNG against the most deflate
can expand); any image, whatever its format, is limited to ``PIL.Image.MAX_IMAGE_PIXELS`` pixels.
Every writer is atomic: the data goes to a temporary file in the target directory that is renamed
onto the target only once it is complete.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from typing import Any

import numpy as np

from ..utils.files import atomic_write
from ..errors import FormatError

__all__ = [
    "read_pfm",
    "write_pfm",
    "read_kitti_disparity",
    "write_kitti_disparity",
    "read_crestereo_disparity",
    "write_crestereo_disparity",
    "read_image",
    "write_image",
    "read_calib",
    "read_npy",
    "write_ply",
]

_KITTI_SCALE = 256.0
_CRESTEREO_SCALE = 32.0
_UINT16_MAX = np.iinfo(np.uint16).max
_HEADER_LINE_MAX = 256  # bytes: a PFM header line is a few characters; anything longer is not a PFM
# Deflate expands at most 1032:1 (a 258-byte match per 2-bit code), so no PNG decodes to more than this
# many bytes per byte of file.
_DEFLATE_MAX_RATIO = 1032


def _format_error(path, message: str) -> FormatError:
    return FormatError(f"{os.fspath(path)}: {message}")


# ----------------------------------------------------------------------------------------- PFM


def read_pfm(path) -> np.ndarray:
    """Read a PFM (portable float map) file.

    Both byte orders are accepted: a negative scale in the header means little-endian data, a
    positive one big-endian. Rows are stored bottom-to-top in the file and returned top-to-bottom.
    Non-finite values (Middlebury and ETH3D mark unknown disparity with ``inf``) are kept.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.pfm`` file.

    Returns
    -------
    numpy.ndarray
        float32 array in native byte order.

    Shapes
    ------
    ``Pf`` (one channel) -> (H, W); ``PF`` (three channels) -> (H, W, 3).

    Raises
    ------
    FormatError
        Bad magic, malformed header, zero scale, or fewer data bytes than the header promises
        (checked against the file size before the data is read).
    """
    with open(path, "rb") as f:
        magic = f.readline(_HEADER_LINE_MAX).strip()
        if magic not in (b"Pf", b"PF"):
            raise _format_error(path, f"not a PFM file (magic {magic[:8]!r}, expected b'Pf' or b'PF')")
        channels = 3 if magic == b"PF" else 1
        width, height = _parse_pfm_size(path, f.readline(_HEADER_LINE_MAX))
        scale = _parse_pfm_scale(path, f.readline(_HEADER_LINE_MAX))
        count = width * height * channels
        available = os.fstat(f.fileno()).st_size - f.tell()
        if 4 * count > available:
            raise _format_error(path, f"truncated PFM: the header claims {width}x{height}x{channels} floats "
                                      f"({4 * count} bytes) but the file holds {available} data bytes")
        data = f.read(4 * count)
    if len(data) < 4 * count:
        raise _format_error(path, f"truncated PFM: {len(data)} data bytes, expected {4 * count}")
    dtype = "<f4" if scale < 0 else ">f4"
    shape = (height, width, channels) if channels == 3 else (height, width)
    image = np.frombuffer(data, dtype=dtype).reshape(shape)
    return np.ascontiguousarray(np.flipud(image), dtype=np.float32)


def _parse_pfm_size(path, line: bytes) -> tuple[int, int]:
    parts = line.split()
    try:
        width, height = (int(p) for p in parts)
    except ValueError:
        raise _format_error(path, f"malformed PFM size line {line[:40]!r}") from None
    if width <= 0 or height <= 0:
        raise _format_error(path, f"invalid PFM size {width}x{height}")
    return width, height


def _parse_pfm_scale(path, line: bytes) -> float:
    try:
        scale = float(line)
    except ValueError:
        raise _format_error(path, f"malformed PFM scale line {line[:40]!r}") from None
    if scale == 0 or not np.isfinite(scale):
        raise _format_error(path, f"invalid PFM scale {scale}")
    return scale


def write_pfm(path, array) -> None:
    """Write a float array as a little-endian PFM (scale ``-1``), rows bottom-to-top.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.pfm`` file (written atomically).
    array : array_like
        Values, converted to float32; ``inf`` and ``nan`` are stored as they are.

    Shapes
    ------
    array: (H, W) or (H, W, 1) -> ``Pf``; (H, W, 3) -> ``PF``.
    """
    image = np.asarray(array, dtype=np.float32)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 2:
        magic = b"Pf"
    elif image.ndim == 3 and image.shape[2] == 3:
        magic = b"PF"
    else:
        raise ValueError(f"write_pfm: expected an (H, W) or (H, W, 3) array, got shape {image.shape}")
    height, width = image.shape[:2]
    header = magic + b"\n" + f"{width} {height}\n-1\n".encode("ascii")
    with atomic_write(path, "wb") as f:
        f.write(header)
        f.write(np.flipud(image).astype("<f4").tobytes())


# ------------------------------------------------------------------------- 16-bit disparity PNGs


def _open_image(path):
    """Open and fully decode an image with Pillow, turning decoder failures into FormatError.

    Pillow reads from the file's bytes in memory, so a chunk length in the file that lies (a PNG
    IDAT claiming 2 GB) cannot make it allocate more than the file holds; the size in the header is
    checked before the pixels are decoded (see :func:`_check_image_size`)."""
    from io import BytesIO

    from PIL import Image

    with open(path, "rb") as f:
        data = f.read()
    try:
        # Pillow only warns between MAX_IMAGE_PIXELS and twice that; here such an image is an error too
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # Pillow's notes on skipped corrupt TIFF/EXIF tags
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(BytesIO(data))
            _check_image_size(path, image, len(data))
            image.load()
    except FormatError:
        raise
    except Exception as exc:  # Pillow raises OSError, ValueError, SyntaxError, EOFError, ...
        raise _format_error(path, f"cannot decode image ({type(exc).__name__}: {exc}; file of {len(data)} bytes)") from None
    return image


def _check_image_size(path, image, file_size: int) -> None:
    """FormatError if the header's size is beyond Pillow's decompression-bomb limit, or (PNG) larger
    than deflate could expand the file to: even a 1-bit image needs ``1 + ceil(W / 8)`` bytes a row."""
    from PIL import Image

    width, height = image.size
    if width * height > Image.MAX_IMAGE_PIXELS:
        raise _format_error(path, f"image header claims {width}x{height} (WxH) = {width * height} pixels, "
                                  f"more than the limit of {Image.MAX_IMAGE_PIXELS} (PIL.Image.MAX_IMAGE_PIXELS)")
    if image.format == "PNG":
        least = height * (1 + -(-width // 8))
        if least > _DEFLATE_MAX_RATIO * file_size:
            raise _format_error(path, f"PNG header claims {width}x{height} (WxH), at least {least} bytes of pixel data, "
                                      f"more than a file of {file_size} bytes can hold")


def _read_uint16_disparity(path, scale: float, kind: str) -> tuple[np.ndarray, np.ndarray]:
    image = _open_image(path)
    if image.mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise _format_error(
            path,
            f"{kind} disparity must be a single-channel 16-bit PNG, got Pillow mode {image.mode!r} "
            "(an 8-bit or colour image is not a disparity map in this format)",
        )
    values = np.asarray(image).astype(np.int64)
    if values.min(initial=0) < 0 or values.max(initial=0) > _UINT16_MAX:
        raise _format_error(path, f"{kind} disparity values outside the uint16 range")
    valid = values > 0
    disparity = (values / scale).astype(np.float32)
    disparity[~valid] = 0.0
    return disparity, valid


def _write_uint16_disparity(path, disparity, valid, scale: float) -> None:
    disp = np.asarray(disparity, dtype=np.float64)
    if disp.ndim != 2:
        raise ValueError(f"expected an (H, W) disparity map, got shape {disp.shape}")
    keep = np.isfinite(disp) & (disp > 0)
    if valid is not None:
        keep &= np.asarray(valid, dtype=bool)
    # A valid positive disparity never rounds down to 0, which would mark it invalid.
    values = np.clip(np.rint(np.where(keep, disp, 0.0) * scale), 1, _UINT16_MAX)
    values = np.where(keep, values, 0).astype(np.uint16)
    _save_pil(path, values, format="PNG")


def read_kitti_disparity(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a KITTI disparity PNG (uint16, disparity = value / 256, value 0 = no ground truth).

    Parameters
    ----------
    path : str or os.PathLike
        16-bit single-channel PNG.

    Returns
    -------
    disparity : numpy.ndarray
        float32, 0 where invalid.
    valid : numpy.ndarray
        bool.

    Shapes
    ------
    disparity, valid: (H, W).

    Raises
    ------
    FormatError
        Undecodable file, or an 8-bit / colour image (mislabelled: not a KITTI disparity map).
    """
    return _read_uint16_disparity(path, _KITTI_SCALE, "KITTI")


def read_crestereo_disparity(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a CREStereo ``*.disp.png`` (uint16, disparity = value / 32, value 0 = invalid).

    Returns ``(disparity float32 (H, W), valid bool (H, W))`` like :func:`read_kitti_disparity`.

    Shapes
    ------
    disparity, valid: (H, W).
    """
    return _read_uint16_disparity(path, _CRESTEREO_SCALE, "CREStereo")


def write_kitti_disparity(path, disparity, valid=None) -> None:
    """Write disparity as a KITTI uint16 PNG (value = round(256 * d)).

    Non-finite, non-positive and (when ``valid`` is given) invalid pixels are stored as 0 (no
    ground truth). Valid values are rounded to the nearest 1/256 px and clipped to
    ``[1, 65535]`` so that a valid pixel stays valid and large values saturate at 255.996 px.

    Parameters
    ----------
    path : str or os.PathLike
        Destination PNG (written atomically).
    disparity : array_like
        Disparity in pixels.
    valid : array_like of bool, optional
        Pixels to keep.

    Shapes
    ------
    disparity, valid: (H, W).
    """
    _write_uint16_disparity(path, disparity, valid, _KITTI_SCALE)


def write_crestereo_disparity(path, disparity, valid=None) -> None:
    """Write disparity as a CREStereo uint16 PNG (value = round(32 * d), max 2047.97 px).

    Same rules as :func:`write_kitti_disparity` with a 1/32 px step.

    Shapes
    ------
    disparity, valid: (H, W).
    """
    _write_uint16_disparity(path, disparity, valid, _CRESTEREO_SCALE)


# ------------------------------------------------------------------------------------ images


def read_image(path) -> np.ndarray:
    """Read an image as RGB uint8.

    Grayscale is replicated to three channels, alpha is dropped, palette images are expanded and
    16-bit images are scaled to 8 bits (value / 257, rounded). No EXIF rotation is applied: stereo
    images must keep their calibrated orientation.

    Parameters
    ----------
    path : str or os.PathLike
        Any format Pillow reads (PNG, JPEG, PPM, TIFF, ...).

    Returns
    -------
    numpy.ndarray
        uint8 RGB.

    Shapes
    ------
    return: (H, W, 3).
    """
    image = _open_image(path)
    if image.mode in ("I;16", "I;16B", "I;16L", "I"):
        gray = np.rint(np.clip(np.asarray(image, dtype=np.float64), 0, _UINT16_MAX) / 257.0)
        return np.repeat(gray.astype(np.uint8)[:, :, None], 3, axis=2)
    if image.mode == "F":
        raise _format_error(path, "floating-point images are not colour images (is this a depth map?)")
    try:
        rgb = image.convert("RGB")
    except (ValueError, OSError) as exc:  # e.g. Pillow has no LAB -> RGB conversion
        raise _format_error(path, f"cannot convert a {image.mode} image of {image.size[0]}x{image.size[1]} (WxH) "
                                  f"to RGB ({exc})") from None
    return np.ascontiguousarray(np.asarray(rgb, dtype=np.uint8))


def write_image(path, image, **save_options: Any) -> None:
    """Write an image; the format follows the file extension (``.png``, ``.jpg``, ``.ppm``, ...).

    Parameters
    ----------
    path : str or os.PathLike
        Destination (written atomically).
    image : array_like
        uint8 image; (H, W) gray, (H, W, 3) RGB or (H, W, 4) RGBA. (H, W, 1) counts as gray.
    **save_options
        Passed to ``PIL.Image.save`` (e.g. ``quality=95`` for JPEG).

    Shapes
    ------
    image: (H, W), (H, W, 1), (H, W, 3) or (H, W, 4).
    """
    array = np.asarray(image)
    if array.dtype != np.uint8:
        raise ValueError(f"write_image: expected a uint8 image, got dtype {array.dtype}")
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] in (3, 4))):
        raise ValueError(f"write_image: expected (H, W), (H, W, 3) or (H, W, 4), got shape {array.shape}")
    _save_pil(path, np.ascontiguousarray(array), format=_pil_format(path), **save_options)


def _pil_format(path) -> str:
    from PIL import Image

    extension = os.path.splitext(os.fspath(path))[1].lower()
    fmt = Image.registered_extensions().get(extension)
    if fmt is None:
        raise ValueError(f"{os.fspath(path)}: unknown image extension {extension!r}")
    return fmt


def _save_pil(path, array: np.ndarray, format: str, **options: Any) -> None:
    from PIL import Image

    image = Image.fromarray(array)
    with atomic_write(path, "wb") as f:
        image.save(f, format=format, **options)


# ------------------------------------------------------------------------------- calibration


def read_calib(path) -> dict:
    """Read a stereo calibration: Middlebury/ETH3D ``calib.txt`` or FoundationStereo ``K.txt``.

    ``calib.txt`` holds ``key=value`` lines: ``cam0=[f 0 cx0; 0 f cy; 0 0 1]``, ``cam1=[...]``,
    ``doffs`` (cx1 - cx0, px), ``baseline`` (mm), ``width``, ``height``, ``ndisp``, ``vmin``,
    ``vmax``, ... ``K.txt`` holds the 9 intrinsics (row-major) on its first line and the baseline
    in metres on its second.

    Parameters
    ----------
    path : str or os.PathLike
        The calibration file; the format is detected from its content (``=`` -> calib.txt).

    Returns
    -------
    dict
        ``fx, fy, cx, cy, doffs, baseline`` (floats) and ``baseline_unit`` (``"mm"`` for
        calib.txt, ``"m"`` for K.txt); plus ``ndisp, width, height`` (int) and ``vmin, vmax``
        (float) when the file has them. ``doffs`` defaults to ``cx1 - cx0`` (or 0 without cam1).

    Shapes
    ------
    scalars only.

    Raises
    ------
    FormatError
        Missing keys, malformed numbers or matrices, non-finite values, a focal length or baseline
        that is not positive, or a non-positive width, height or ndisp.
    """
    with open(path, encoding="utf-8", errors="replace") as f:
        text = f.read()
    calib = _parse_middlebury_calib(path, text) if "=" in text else _parse_k_txt(path, text)
    _check_calib(path, calib)
    return calib


def _check_calib(path, calib: dict) -> None:
    """FormatError unless every number is finite and fx, fy, baseline (and width, height, ndisp) are positive."""
    for key, value in calib.items():
        if isinstance(value, float) and not np.isfinite(value):
            raise _format_error(path, f"calibration value {key}={value} is not finite")
    for key in ("fx", "fy", "baseline", "width", "height", "ndisp"):
        if key in calib and not calib[key] > 0:
            raise _format_error(path, f"calibration value {key}={calib[key]} must be positive")


def _parse_numbers(path, text: str, what: str) -> list[float]:
    try:
        return [float(t) for t in re.split(r"[\s;,\[\]]+", text.strip()) if t]
    except ValueError:
        raise _format_error(path, f"malformed numbers in {what}: {text.strip()[:60]!r}") from None


def _parse_matrix3(path, text: str, key: str) -> list[float]:
    values = _parse_numbers(path, text, key)
    if len(values) != 9:
        raise _format_error(path, f"{key} must be a 3x3 matrix, got {len(values)} numbers")
    return values


def _parse_middlebury_calib(path, text: str) -> dict:
    entries: dict[str, str] = {}
    for line in text.splitlines():
        if "=" in line:
            key, value = line.split("=", 1)
            entries[key.strip()] = value.strip()
    for key in ("cam0", "baseline"):
        if key not in entries:
            raise _format_error(path, f"calib.txt lacks the {key!r} entry")
    cam0 = _parse_matrix3(path, entries["cam0"], "cam0")
    calib: dict[str, Any] = {
        "fx": cam0[0],
        "fy": cam0[4],
        "cx": cam0[2],
        "cy": cam0[5],
        "doffs": 0.0,
        "baseline": _scalar(path, entries, "baseline", float),
        "baseline_unit": "mm",
    }
    if "cam1" in entries:
        calib["doffs"] = _parse_matrix3(path, entries["cam1"], "cam1")[2] - calib["cx"]
    if "doffs" in entries:
        calib["doffs"] = _scalar(path, entries, "doffs", float)
    for key, kind in (("ndisp", int), ("width", int), ("height", int), ("vmin", float), ("vmax", float)):
        if key in entries:
            calib[key] = _scalar(path, entries, key, kind)
    return calib


def _scalar(path, entries: dict, key: str, kind):
    try:
        value = float(entries[key])
    except ValueError:
        raise _format_error(path, f"malformed {key}={entries[key][:40]!r}") from None
    if kind is int:
        if not value.is_integer():
            raise _format_error(path, f"{key} must be an integer, got {entries[key][:40]!r}")
        return int(value)
    return value


def _parse_k_txt(path, text: str) -> dict:
    lines = [line for line in text.splitlines() if line.strip()]
    if len(lines) < 2:
        raise _format_error(path, "K.txt needs 9 intrinsics on line 1 and the baseline (m) on line 2")
    k = _parse_matrix3(path, lines[0], "K")
    baseline = _parse_numbers(path, lines[1], "baseline")
    if len(baseline) != 1:
        raise _format_error(path, f"K.txt line 2 must hold one baseline value, got {len(baseline)}")
    return {"fx": k[0], "fy": k[4], "cx": k[2], "cy": k[5], "doffs": 0.0,
            "baseline": baseline[0], "baseline_unit": "m"}


# ------------------------------------------------------------------------------------- NPY


def read_npy(path) -> np.ndarray:
    """Read a ``.npy`` array (no pickled objects).

    Parameters
    ----------
    path : str or os.PathLike
        A file written by ``numpy.save``.

    Returns
    -------
    numpy.ndarray
        The array, with the dtype and shape its header names.

    Shapes
    ------
    as stored.

    Raises
    ------
    FormatError
        Not a ``.npy`` file, a malformed header, an object dtype, or fewer data bytes than the header
        promises (checked against the file size before the data is read).
    """
    from tokenize import TokenError

    from numpy.lib import format as npy

    with open(path, "rb") as f:
        try:
            version = npy.read_magic(f)
            if version not in ((1, 0), (2, 0)):
                raise ValueError(f"unsupported .npy version {version[0]}.{version[1]} (1.0 and 2.0 are read)")
            # the header length: 2 bytes (version 1.0) or 4 bytes (2.0), little-endian, after the magic
            width = 2 if version == (1, 0) else 4
            length = int.from_bytes(f.read(width), "little")
            if length > os.fstat(f.fileno()).st_size - f.tell():
                raise ValueError(f"header length {length} exceeds the file size")
            f.seek(-width, os.SEEK_CUR)
            read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
            shape, fortran_order, dtype = read_header(f)
        except (ValueError, EOFError, SyntaxError, TypeError, TokenError, RecursionError) as exc:
            # numpy parses the header dict with tokenize and ast.literal_eval, which raise all of these
            raise _format_error(path, f"not a valid .npy file ({type(exc).__name__}: {exc})") from None
        if not isinstance(shape, tuple) or not all(isinstance(d, int) and d >= 0 for d in shape):
            raise _format_error(path, f"the .npy header has an invalid shape {str(shape)[:60]}")
        if dtype.hasobject:
            raise _format_error(path, f"the .npy file holds Python objects (dtype {dtype}), which are not read")
        count = math.prod(shape)
        available = os.fstat(f.fileno()).st_size - f.tell()
        if count * dtype.itemsize > available:
            raise _format_error(path, f"truncated .npy: the header claims shape {list(shape)} of {dtype} "
                                      f"({count * dtype.itemsize} bytes) but the file holds {available} data bytes")
        data = np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype, count=count)
    order = "F" if fortran_order else "C"
    return data.reshape(shape, order=order).copy(order="K")


# ------------------------------------------------------------------------------------- PLY


def write_ply(path, points, colors=None) -> None:
    """Write a point cloud as binary little-endian PLY (x, y, z float32; red, green, blue uint8), with
    the ``plyfile`` package.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.ply`` (written atomically).
    points : array_like
        Coordinates, converted to float32.
    colors : array_like of uint8, optional
        Per-point RGB; omitted from the file when None.

    Shapes
    ------
    points: (N, 3); colors: (N, 3).
    """
    from plyfile import PlyData, PlyElement

    xyz = np.asarray(points, dtype=np.float32)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"write_ply: points must have shape (N, 3), got {xyz.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        rgb = np.asarray(colors)
        if rgb.dtype != np.uint8 or rgb.shape != xyz.shape:
            raise ValueError(f"write_ply: colors must be uint8 of shape {xyz.shape}, got {rgb.dtype} {rgb.shape}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vertices = np.empty(len(xyz), dtype=fields)
    for axis, name in enumerate("xyz"):
        vertices[name] = xyz[:, axis]
    if colors is not None:
        for axis, name in enumerate(("red", "green", "blue")):
            vertices[name] = rgb[:, axis]
    ply = PlyData([PlyElement.describe(vertices, "vertex")], text=False, byte_order="<")
    with atomic_write(path, "wb") as f:
        ply.write(f)
