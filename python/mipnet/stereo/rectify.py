"""Raw pairs from a calibrated stereo rig: read an OpenCV stereo calibration, rectify with OpenCV, and turn the
rectified disparity into depth.

A *rig calibration* is what ``cv2.stereoCalibrate`` returns for a two-camera rig: the intrinsics ``K1``, ``K2``
(3x3), the distortion coefficients ``D1``, ``D2`` (OpenCV's pinhole model, 4, 5, 8, 12 or 14 of them), and the
pose of the second camera in the first's frame, ``X2 = R @ X1 + T`` (``R`` a 3x3 rotation or a Rodrigues
vector, ``T`` 3 numbers). It is stored in the YAML, XML or JSON that ``cv2.FileStorage`` writes, with the optional
``image_width`` and ``image_height`` (pixels) of the images it was made from (see docs/calibration.md).

Rectification (:class:`Rectifier`) runs ``cv2.stereoRectify`` (flag ``CALIB_ZERO_DISPARITY``: both rectified
principal points coincide, so ``Z = f * B / d`` with no disparity offset) and ``cv2.initUndistortRectifyMap``
once per image size, then ``cv2.remap`` per pair (bilinear, float maps). In the rectified frame

    f = P1[0, 0]                  the rectified focal length, in pixels,
    B = -P2[0, 3] / P2[0, 0]      the baseline, in the units of T,
    Z = f * B / d                 depth along the rectified left camera's optical axis, in the units of T,

so depth is in metres when the calibration's ``T`` is (a checkerboard measured in metres), in millimetres when
it is in millimetres. ``alpha`` is stereoRectify's free scaling: the default 0 zooms the rectified images until
every pixel comes from inside both source images (no black borders for the network to match), 1 keeps every
source pixel and leaves black borders; values between blend the two.

The depth of already-rectified pairs (Middlebury ``calib.txt``, ``K.txt``) is docs/architecture.md §3.5;
:func:`open_calibration` reads either kind of file. OpenCV is an optional dependency (``pip install mipnet[calib]``
or ``opencv-python-headless``), imported on first use.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from ..errors import ArgumentError, FormatError, ShapeError
from . import geometry, io

__all__ = ["StereoRig", "Rectification", "Rectifier", "RectifiedPair", "rectify", "is_rig_calibration",
           "open_calibration", "RIG_SUFFIXES", "DISTORTION_LENGTHS", "KEY_ALIASES"]

#: file suffixes of the formats ``cv2.FileStorage`` writes; other files are recognised by their first bytes
RIG_SUFFIXES = (".yml", ".yaml", ".xml", ".json")
#: the lengths of OpenCV's pinhole distortion vector (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]])
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
#: the names each entry of a rig calibration is read under: the issue's / stereoCalibrate's output names first,
#: then those of OpenCV's stereo_calib sample (M1, M2) and of its C++ parameter names
KEY_ALIASES = {
    "K1": ("K1", "M1", "cameraMatrix1"),
    "D1": ("D1", "distCoeffs1"),
    "K2": ("K2", "M2", "cameraMatrix2"),
    "D2": ("D2", "distCoeffs2"),
    "R": ("R",),
    "T": ("T",),
}
_ROTATION_TOLERANCE = 1e-3  # max |R^T R - I| of a rotation matrix, allowing one written by hand to 4 digits


def _import_cv2():
    """OpenCV, or an ArgumentError saying how to install it."""
    try:
        import cv2
    except ImportError:
        raise ArgumentError("rectifying raw pairs from a stereo rig calibration needs OpenCV: "
                            "pip install opencv-python-headless (or mipnet[calib])") from None
    return cv2


def _format_error(source: str, message: str) -> FormatError:
    return FormatError(f"{source}: {message}")


def _check_camera(what: str, camera) -> None:
    if camera not in (0, 1) or isinstance(camera, bool):
        raise ArgumentError(f"{what}: camera must be 0 (left) or 1 (right), got {camera!r}")


def is_rig_calibration(path) -> bool:
    """True if ``path`` holds a ``cv2.FileStorage`` file (a rig calibration) rather than a Middlebury
    ``calib.txt`` or a ``K.txt``: by its suffix (:data:`RIG_SUFFIXES`), else by its first bytes
    (``%YAML``, ``<?xml``, ``<opencv_storage>`` or ``{``)."""
    if os.fspath(path).lower().endswith(RIG_SUFFIXES):
        return True
    with open(path, "rb") as f:
        head = f.read(64).lstrip()
    return head.startswith((b"%YAML", b"<?xml", b"<opencv_storage", b"{"))


# ---- the calibration -------------------------------------------------------------------------------


def _vector(source: str, key: str, value, lengths: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float64 vector of one of ``lengths``; a row, a column or a flat list are all accepted."""
    array = np.asarray(value, dtype=np.float64)
    if array.ndim > 2 or (array.ndim == 2 and 1 not in array.shape) or array.size not in lengths:
        expected = " or ".join(str(n) for n in lengths)
        raise _format_error(source, f"{key} must be a vector of {expected} numbers (1xN or Nx1), "
                                    f"got shape {list(array.shape)}")
    return array.reshape(-1)


def _camera_matrix(source: str, key: str, value) -> np.ndarray:
    """``value`` as a 3x3 intrinsic matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0."""
    k = np.asarray(value, dtype=np.float64)
    if k.shape != (3, 3):
        raise _format_error(source, f"{key} must be a 3x3 camera matrix, got shape {list(k.shape)}")
    if not np.allclose(k[2], [0.0, 0.0, 1.0]) or not (k[0, 0] > 0 and k[1, 1] > 0):
        raise _format_error(source, f"{key} is not a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with "
                                    f"fx, fy > 0: {k.tolist()}")
    return k


def _rotation(source: str, value, cv2) -> np.ndarray:
    """``value`` as a 3x3 rotation matrix: a 3x3 matrix is checked (R^T R = I, det R = +1), a 3-vector is taken
    as a Rodrigues rotation vector."""
    r = np.asarray(value, dtype=np.float64)
    if r.shape != (3, 3):
        return cv2.Rodrigues(_vector(source, "R (a 3x3 matrix or a Rodrigues vector)", r, (3,)))[0]
    if np.abs(r.T @ r - np.eye(3)).max() > _ROTATION_TOLERANCE or np.linalg.det(r) < 0:
        raise _format_error(source, f"R is not a rotation matrix (R^T R != I or det R < 0): {r.tolist()}")
    return r


class StereoRig:
    """The calibration of a two-camera rig, as ``cv2.stereoCalibrate`` returns it.

    Parameters
    ----------
    K1, K2 : array_like
        Intrinsic matrices of the first (left) and second (right) camera, pixels.
    D1, D2 : array_like
        Distortion coefficients (OpenCV pinhole model), 4, 5, 8, 12 or 14 each.
    R : array_like
        Rotation from the first camera's frame to the second's: a 3x3 matrix or a Rodrigues vector.
    T : array_like
        Translation from the first camera's frame to the second's (``X2 = R @ X1 + T``); its units are the
        units of every depth computed from this rig.
    image_size : (int, int), optional
        (height, width) of the images the calibration was made from; pairs of another size are refused.
        None: any size is taken as the calibrated one.
    source : str
        What error messages name (the file it was read from).

    Shapes
    ------
    K1, K2: (3, 3); D1, D2: (N,), (1, N) or (N, 1) with N in 4, 5, 8, 12, 14; R: (3, 3) or 3 numbers;
    T: 3 numbers. Stored as float64 (3, 3), (N,), (3, 3) and (3,).

    Raises
    ------
    FormatError
        A matrix of the wrong shape, non-finite numbers, a camera matrix that is not one, a rotation that is
        not one, a zero translation, or an image size that is not two positive integers.
    """

    def __init__(self, K1, D1, K2, D2, R, T, image_size: tuple[int, int] | None = None,
                 source: str = "stereo calibration"):
        cv2 = _import_cv2()
        self.source = source
        self.K1, self.K2 = _camera_matrix(source, "K1", K1), _camera_matrix(source, "K2", K2)
        self.D1 = _vector(source, "D1", D1, DISTORTION_LENGTHS)
        self.D2 = _vector(source, "D2", D2, DISTORTION_LENGTHS)
        self.T = _vector(source, "T", T, (3,))
        for key in ("K1", "K2", "D1", "D2", "T"):
            if not np.isfinite(getattr(self, key)).all():
                raise _format_error(source, f"{key} holds non-finite numbers: {getattr(self, key).tolist()}")
        if not np.isfinite(np.asarray(R, dtype=np.float64)).all():
            raise _format_error(source, "R holds non-finite numbers")
        self.R = _rotation(source, R, cv2)
        if not np.linalg.norm(self.T) > 0:
            raise _format_error(source, "T is zero: the two cameras are at one place, there is no baseline")
        if image_size is not None:
            height, width = image_size
            if not all(isinstance(n, (int, np.integer)) and n > 0 for n in (height, width)):
                raise _format_error(source, f"the image size must be two positive integers, got {image_size}")
            image_size = (int(height), int(width))
        self.image_size = image_size

    @classmethod
    def read(cls, path) -> StereoRig:
        """Reads a rig calibration written by ``cv2.FileStorage`` (``.yml``/``.yaml``, ``.xml``, ``.json``).

        The entries ``K1, D1, K2, D2, R, T`` (also under the names of :data:`KEY_ALIASES`) are OpenCV matrices
        (``!!opencv-matrix`` in YAML, ``type_id="opencv-matrix"`` in XML and JSON) or plain lists of numbers /
        lists of rows; ``image_width`` and ``image_height`` are optional integers (both or neither).

        Raises
        ------
        FileNotFoundError, IsADirectoryError
            ``path`` is not a file.
        FormatError
            A file ``cv2.FileStorage`` cannot parse, a missing entry (the message names it), or an entry of the
            wrong kind or shape.
        """
        cv2 = _import_cv2()
        source = os.fspath(path)
        if not os.path.exists(source):
            raise FileNotFoundError(2, "no such calibration file", source)
        if os.path.isdir(source):
            raise IsADirectoryError(21, "a calibration file is expected, not a folder", source)
        try:
            storage = cv2.FileStorage(source, cv2.FILE_STORAGE_READ)
        except (cv2.error, SystemError) as exc:
            # a parse error reaches Python as SystemError whose cause is the cv2.error
            reason = str(exc.__cause__ or exc).strip().splitlines()[-1]
            raise _format_error(source, f"not a YAML/XML/JSON file cv2.FileStorage can read ({reason})") from None
        try:
            if not storage.isOpened() or not storage.root().isMap():
                raise _format_error(source, "not a YAML/XML/JSON file cv2.FileStorage can read")
            entries = {key: _node_value(source, key, storage.getNode(key)) for key in storage.root().keys()}
        finally:
            storage.release()
        matrices = {name: _entry(source, entries, name) for name in KEY_ALIASES}
        return cls(**matrices, image_size=_image_size(source, entries), source=source)

    def __repr__(self) -> str:
        return (f"StereoRig(source={self.source!r}, image_size={self.image_size}, "
                f"baseline={np.linalg.norm(self.T):.6g} (units of T))")


def _node_value(source: str, key: str, node):
    """A ``cv2.FileNode`` as a numpy array (an OpenCV matrix, a number, a list of numbers or of rows), or None for
    anything else (strings, maps that are not matrices): such entries are only an error if they are used."""
    if node.isInt() or node.isReal():
        return np.float64(node.real())
    if node.isMap():
        if node.getNode("data").empty():  # a map, but not an OpenCV matrix (rows, cols, dt, data)
            return None
        try:
            return np.asarray(node.mat(), dtype=np.float64)
        except Exception as exc:  # cv2.error / SystemError from a malformed matrix entry
            raise _format_error(source, f"{key} is a malformed OpenCV matrix ({str(exc).strip()[:120]})") from None
    if node.isSeq():
        items = [_node_value(source, key, node.at(i)) for i in range(node.size())]
        if any(item is None for item in items):
            return None
        try:
            return np.array(items, dtype=np.float64)
        except ValueError:
            raise _format_error(source, f"{key} is a list of rows of different lengths") from None
    return None


def _entry(source: str, entries: Mapping, name: str) -> np.ndarray:
    """The entry ``name`` under the first of its names (:data:`KEY_ALIASES`) the file has."""
    names = KEY_ALIASES[name]
    for alias in names:
        if alias in entries:
            if entries[alias] is None:
                raise _format_error(source, f"{alias} is not a matrix or a list of numbers")
            return entries[alias]
    aliases = f" (or {', '.join(names[1:])})" if len(names) > 1 else ""
    present = ", ".join(entries) or "none"
    raise _format_error(source, f"the stereo calibration lacks the {name!r} entry{aliases}; it has: {present}")


def _image_size(source: str, entries: Mapping) -> tuple[int, int] | None:
    """(height, width) from ``image_height`` / ``image_width``, or None if the file has neither."""
    present = [key for key in ("image_height", "image_width") if key in entries]
    if not present:
        return None
    if len(present) == 1:
        missing = "image_width" if present == ["image_height"] else "image_height"
        raise _format_error(source, f"the stereo calibration has {present[0]} but lacks the {missing!r} entry")
    values = [entries[key] for key in ("image_height", "image_width")]
    if not all(isinstance(v, np.float64) and v.is_integer() and v > 0 for v in values):
        raise _format_error(source, f"image_height and image_width must be positive integers, got "
                                    f"{[v.tolist() if v is not None else None for v in values]}")
    return int(values[0]), int(values[1])


# ---- rectification -------------------------------------------------------------------------------


class Rectification:
    """The rectification of one rig at one image size: ``cv2.stereoRectify``'s transforms and the remap tables.

    Attributes
    ----------
    size : (int, int)
        (height, width) of the raw and of the rectified images.
    R1, R2 : numpy.ndarray
        (3, 3) rotations from each raw camera frame to its rectified frame.
    P1, P2 : numpy.ndarray
        (3, 4) projections of the rectified left camera frame into each rectified image.
    Q : numpy.ndarray
        (4, 4) disparity-to-depth matrix (``cv2.reprojectImageTo3D``).
    focal : float
        Rectified focal length f = P1[0, 0], pixels.
    baseline : float
        B = -P2[0, 3] / P2[0, 0], in the units of the rig's T.
    maps : tuple
        ((map_x, map_y) of the left camera, (map_x, map_y) of the right), each (H, W) float32: rectified pixel
        (u, v) takes the raw image's value at (map_x[v, u], map_y[v, u]).
    """

    def __init__(self, rig: StereoRig, size: tuple[int, int], alpha: float):
        cv2 = _import_cv2()
        height, width = size
        self.size = (int(height), int(width))
        self.R1, self.R2, self.P1, self.P2, self.Q, _, _ = cv2.stereoRectify(
            rig.K1, rig.D1, rig.K2, rig.D2, (width, height), rig.R, rig.T.reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha)
        # horizontal rigs put the baseline in P2[0, 3] = f * Tx; vertical ones in P2[1, 3] = f * Ty
        if abs(self.P2[1, 3]) > abs(self.P2[0, 3]):
            raise _format_error(rig.source, f"the cameras are one above the other (T = {rig.T.tolist()}): "
                                            "mipnet matches side-by-side pairs; rotate the images and the "
                                            "calibration by 90 degrees")
        self.focal = float(self.P1[0, 0])
        self.baseline = float(-self.P2[0, 3] / self.P2[0, 0])
        if not self.baseline > 0:
            raise _format_error(rig.source, f"the second camera is LEFT of the first (T = {rig.T.tolist()}, "
                                            "rectified baseline negative): give the left camera as the first "
                                            "one (swap the images and K1/D1 with K2/D2, and invert R, T)")
        # per camera: raw intrinsics, distortion, rectifying rotation, rectified projection
        self._cameras = ((rig.K1, rig.D1, self.R1, self.P1), (rig.K2, rig.D2, self.R2, self.P2))
        self.maps = tuple(cv2.initUndistortRectifyMap(k, d, r, p, (width, height), cv2.CV_32FC1)
                          for k, d, r, p in self._cameras)

    def remap(self, image: np.ndarray, camera: int) -> np.ndarray:
        """The raw image of ``camera`` (0 left, 1 right) rectified: bilinear, black outside the raw image.

        Shapes
        ------
        image: (H, W) or (H, W, C) of any dtype cv2.remap takes (uint8, uint16, float32, ...); return: the same.
        """
        cv2 = _import_cv2()
        _check_camera("Rectification.remap", camera)
        map_x, map_y = self.maps[camera]
        return cv2.remap(np.ascontiguousarray(image), map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def rectify_points(self, points, camera: int) -> np.ndarray:
        """Pixel positions in the raw image of ``camera`` (0 left, 1 right) -> their positions in its rectified
        image (distortion removed by iterating to convergence, then R1/R2 and P1/P2).

        Shapes
        ------
        points: (N, 2) as (x, y) pixels; return: (N, 2) float64.
        """
        cv2 = _import_cv2()
        _check_camera("Rectification.rectify_points", camera)
        intrinsics, distortion, rotation, projection = self._cameras[camera]
        src = np.asarray(points, dtype=np.float64).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x; 5.x gives undistortPoints a criteria argument
            out = cv2.undistortPointsIter(src, intrinsics, distortion, rotation, projection, criteria)
        else:
            out = cv2.undistortPoints(src, intrinsics, distortion, R=rotation, P=projection, criteria=criteria)
        return out.reshape(-1, 2)

    def depth_calibration(self) -> dict:
        """The rectified left camera as :mod:`mipnet.stereo.geometry` takes it: ``fx = fy = f``, ``cx, cy`` of
        P1, ``doffs = 0`` (zero-disparity rectification), ``baseline = B`` with ``baseline_unit`` "m" (depth comes
        out in the units of T)."""
        return {"fx": self.focal, "fy": float(self.P1[1, 1]), "cx": float(self.P1[0, 2]),
                "cy": float(self.P1[1, 2]), "doffs": float(self.P2[0, 2] - self.P1[0, 2]),
                "baseline": self.baseline, "baseline_unit": "m"}

    def depth(self, disparity) -> np.ndarray:
        """Depth ``Z = f * B / d`` in the units of T (+inf where the disparity is not positive or not finite).

        Shapes
        ------
        disparity: (H, W) left-view disparity of the rectified pair, pixels; return: (H, W) float32.
        """
        disparity = np.asarray(disparity)
        if disparity.shape != self.size:
            raise ShapeError(f"Rectification.depth: the disparity is {list(disparity.shape)} but this rectification "
                             f"is for {self.size[0]}x{self.size[1]} (HxW) images")
        return geometry.disparity_to_depth(disparity, self.depth_calibration())


class RectifiedPair(NamedTuple):
    """A rectified pair: images (the raw ones' shape and dtype), the rectified focal length (pixels) and the
    baseline (units of T); ``depth = focal * baseline / disparity``."""

    left: np.ndarray
    right: np.ndarray
    focal: float
    baseline: float


class Rectifier:
    """Rectifies the raw pairs of one rig: stereoRectify and the remap tables are computed once per image size
    and kept.

    Parameters
    ----------
    rig : StereoRig or str or os.PathLike
        The calibration, or the file to read it from (:meth:`StereoRig.read`).
    alpha : float
        stereoRectify's free scaling in [0, 1]: 0 (default) keeps only pixels seen by the raw cameras (no black
        borders), 1 keeps every raw pixel (black borders).

    Examples
    --------
    >>> rectifier = Rectifier("rig.yml")                         # doctest: +SKIP
    >>> left_r, right_r, f, B = rectifier.rectify(left, right)   # doctest: +SKIP
    >>> depth = rectifier.depth(model(left_r, right_r))          # doctest: +SKIP
    """

    def __init__(self, rig, alpha: float = 0.0):
        if not isinstance(rig, StereoRig):
            rig = StereoRig.read(rig)
        if not 0.0 <= float(alpha) <= 1.0:
            raise ArgumentError(f"the rectification alpha (stereoRectify's free scaling) must be in [0, 1], "
                                f"got {alpha}")
        self.rig, self.alpha = rig, float(alpha)
        self._by_size: dict[tuple[int, int], Rectification] = {}

    def rectification(self, size: tuple[int, int]) -> Rectification:
        """The rectification for images of ``size`` (height, width), computed on first use.

        Raises
        ------
        ShapeError
            The rig was calibrated on images of another size.
        """
        size = (int(size[0]), int(size[1]))
        expected = self.rig.image_size
        if expected is not None and size != expected:
            raise ShapeError(f"{self.rig.source}: the calibration is for {expected[0]}x{expected[1]} (HxW) images "
                             f"but the pair is {size[0]}x{size[1]}: resize the images to the calibrated size or "
                             "calibrate at this one")
        if size not in self._by_size:
            self._by_size[size] = Rectification(self.rig, size, self.alpha)
        return self._by_size[size]

    def rectify(self, left, right) -> RectifiedPair:
        """Rectifies a raw pair.

        Shapes
        ------
        left, right: (H, W, C) or (H, W), one shape; the rectified images have it too.

        Raises
        ------
        ShapeError
            The two images differ in shape, are not images, or are not of the calibrated size.
        """
        left, right = np.asarray(left), np.asarray(right)
        if left.shape != right.shape or left.ndim not in (2, 3):
            raise ShapeError(f"rectify: the left and right images must be (H, W) or (H, W, C) of one shape, got "
                             f"{list(left.shape)} and {list(right.shape)}")
        rectification = self.rectification(left.shape[:2])
        return RectifiedPair(rectification.remap(left, 0), rectification.remap(right, 1), rectification.focal,
                             rectification.baseline)

    def calibration(self, size: tuple[int, int]) -> dict:
        """:meth:`Rectification.depth_calibration` at ``size`` (height, width)."""
        return self.rectification(size).depth_calibration()

    def depth(self, disparity) -> np.ndarray:
        """Depth in the units of T from a disparity of a rectified pair (:meth:`Rectification.depth`).

        Shapes
        ------
        disparity: (H, W); return: (H, W) float32.
        """
        disparity = np.asarray(disparity)
        if disparity.ndim != 2:
            raise ShapeError(f"Rectifier.depth: expected an (H, W) disparity, got shape {list(disparity.shape)}")
        return self.rectification(disparity.shape).depth(disparity)


def rectify(left, right, calib, alpha: float = 0.0) -> RectifiedPair:
    """Rectifies a raw stereo pair with a rig calibration (see :class:`Rectifier`, which keeps the remap tables
    between calls: use it for more than one pair).

    Parameters
    ----------
    left, right : numpy.ndarray
        The raw images of the first (left) and second (right) camera.
    calib : Rectifier, StereoRig, str or os.PathLike
        The rig, or the ``cv2.FileStorage`` file holding its calibration.
    alpha : float
        stereoRectify's free scaling (0: valid pixels only, the default; 1: all raw pixels); ignored for a
        Rectifier, which has its own.

    Returns
    -------
    RectifiedPair
        ``(left, right, focal, baseline)``: the rectified images, f in pixels, B in the units of T.

    Shapes
    ------
    left, right: (H, W, 3) or (H, W), one shape; the rectified images: the same.
    """
    rectifier = calib if isinstance(calib, Rectifier) else Rectifier(calib, alpha=alpha)
    return rectifier.rectify(left, right)


def open_calibration(path, alpha: float | None = None) -> Rectifier | dict:
    """The calibration a file holds, whichever kind: a :class:`Rectifier` for an OpenCV rig calibration
    (:func:`is_rig_calibration`; raw pairs are rectified first), else the dict of
    :func:`mipnet.stereo.io.read_calib` (Middlebury ``calib.txt`` or ``K.txt``, for pairs already rectified).

    Parameters
    ----------
    path : str or os.PathLike
        The calibration file.
    alpha : float, optional
        stereoRectify's free scaling for a rig (default 0); an error for an already-rectified calibration.

    Raises
    ------
    ArgumentError
        ``alpha`` given with a calibration of rectified pairs, or OpenCV missing for a rig.
    FormatError
        A malformed calibration (the message names the file and the entry).
    """
    if is_rig_calibration(path):
        return Rectifier(StereoRig.read(path), alpha=0.0 if alpha is None else alpha)
    if alpha is not None:
        raise ArgumentError(f"{os.fspath(path)}: a rectification alpha applies to an OpenCV stereo rig calibration "
                            "(.yml/.yaml/.xml/.json), but this file calibrates pairs that are already rectified")
    return io.read_calib(path)
