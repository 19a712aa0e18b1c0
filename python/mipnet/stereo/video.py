"""Stereo video in and disparity video out, through PyAV (FFmpeg): the I/O of ``mipnet infer --video / --sbs /
--sequence`` (docs/video.md).

Frame pairs come from one of three sources, each iterable as ``(name, left, right)`` with RGB uint8 frames:

* :class:`VideoPair`: two videos, one per camera, frame i of one with frame i of the other;
* :class:`SideBySide`: one video whose frames hold the left view in their left half and the right view in their
  right half;
* :class:`ImagePairs`: image files, a sorted sequence per camera.

A disparity video is written with ONE colour range for the whole sequence (:class:`DisparityVideo`): a colour means
the same disparity in every frame. The range is the 1st and 99th percentile of every disparity of the sequence,
pooled (:func:`pooled_percentiles`, a second pass over the saved disparities, exact to 1/4096 of the span), unless
fixed by hand; it is stored in the video's ``comment`` metadata as JSON (:func:`read_colour_range`).
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Callable, Iterable, Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import ArgumentError, FormatError, ShapeError
from ..utils.files import atomic_write
from .io import read_image
from .viz import colorize

__all__ = ["VideoPair", "SideBySide", "ImagePairs", "DisparityVideo", "pooled_percentiles", "read_colour_range",
           "read_frames", "DEFAULT_FPS", "HISTOGRAM_BINS"]

#: Frame rate of a disparity video made from image files (which carry none).
DEFAULT_FPS = 10.0
#: Bins of the histogram :func:`pooled_percentiles` reads the percentiles from.
HISTOGRAM_BINS = 4096
_CODEC, _PIXEL_FORMAT, _QUALITY = "libx264", "yuv420p", "18"  # H.264, the format every player reads; crf 18


def _av():
    """The ``av`` module (PyAV), or ArgumentError saying how to install it."""
    try:
        import av
    except ImportError:
        raise ArgumentError("video input and output need PyAV: pip install av (or pip install 'mipnet[video]')") \
            from None
    return av


def _check_file(path: str) -> None:
    if not os.path.exists(path):
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), path)
    if not os.path.isfile(path):
        raise IsADirectoryError(errno.EISDIR, "not a file", path)


class _Video:
    """One video file open for reading its first video stream as RGB frames."""

    def __init__(self, path: str):
        av = _av()
        _check_file(path)
        self.path = path
        try:
            self.container = av.open(path)
        except av.error.FFmpegError as error:
            raise FormatError(f"{path}: not a readable video ({error})") from None
        if not self.container.streams.video:
            self.container.close()
            raise FormatError(f"{path}: holds no video stream")
        self.stream = self.container.streams.video[0]
        self.size = (self.stream.codec_context.height, self.stream.codec_context.width)
        self.count = int(self.stream.frames) or None  # 0: the container does not say
        rate = self.stream.average_rate or self.stream.guessed_rate
        self.fps = float(rate) if rate else DEFAULT_FPS

    def frames(self) -> Iterator[np.ndarray]:
        """The frames in order, (H, W, 3) uint8 RGB; FormatError naming the file if decoding fails."""
        av = _av()
        try:
            for frame in self.container.decode(self.stream):
                yield frame.to_ndarray(format="rgb24")
        except av.error.FFmpegError as error:
            raise FormatError(f"{self.path}: cannot decode a frame ({error})") from None
        finally:
            self.container.close()


def read_frames(path: str) -> list[np.ndarray]:
    """Every frame of a video, (H, W, 3) uint8 RGB each."""
    return list(_Video(str(path)).frames())


class VideoPair:
    """Frame pairs from two videos, the left camera's and the right camera's, frame by frame.

    Raises ShapeError (before any frame is read) if the two differ in frame size, and FormatError if they differ
    in length: before any work where the containers state their frame counts, else where the shorter one ends.

    Shapes
    ------
    each item: (name, left (H, W, 3) uint8, right (H, W, 3) uint8).
    """

    def __init__(self, left: str, right: str):
        self.left, self.right = _Video(str(left)), _Video(str(right))
        if self.left.size != self.right.size:
            raise ShapeError(f"{left} has {self.left.size[0]}x{self.left.size[1]} (HxW) frames but {right} has "
                             f"{self.right.size[0]}x{self.right.size[1]}: the two videos of a pair must have one size")
        if self.left.count and self.right.count and self.left.count != self.right.count:
            raise FormatError(f"{left} has {self.left.count} frames but {right} has {self.right.count}: "
                              "the two videos of a pair must have one length")
        self.count, self.fps, self.stem = self.left.count, self.left.fps, Path(left).stem

    def __iter__(self) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
        done = object()
        lefts, rights = self.left.frames(), self.right.frames()
        index = 0
        while True:
            left, right = next(lefts, done), next(rights, done)
            if left is done or right is done:
                if left is not right:
                    shorter = self.left.path if left is done else self.right.path
                    raise FormatError(f"{shorter} ends after {index} frames, before the other video of the pair "
                                      f"({self.left.path}, {self.right.path}): the two must have one length")
                return
            yield f"{self.stem}_{index:06d}", left, right
            index += 1


class SideBySide:
    """Frame pairs from one side-by-side video: the left half of each frame is the left view, the right half the
    right view. ShapeError if the frame width is odd.

    Shapes
    ------
    each item: (name, left (H, W/2, 3) uint8, right (H, W/2, 3) uint8).
    """

    def __init__(self, path: str):
        self.video = _Video(str(path))
        height, width = self.video.size
        if width % 2:
            raise ShapeError(f"{path}: side-by-side frames must have an even width, got {height}x{width} (HxW)")
        self.count, self.fps, self.stem = self.video.count, self.video.fps, Path(path).stem

    def __iter__(self) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
        half = self.video.size[1] // 2
        for index, frame in enumerate(self.video.frames()):
            # columns [0, W/2) are the left view, [W/2, W) the right view
            yield f"{self.stem}_{index:06d}", frame[:, :half], frame[:, half:]


class ImagePairs:
    """Frame pairs from image files, in order: ``(left path, right path, output name)`` per frame (as
    :func:`mipnet.inference.resolve_pairs` lists a sorted image sequence per camera).

    ShapeError (when the frame is read) if the two images of a pair, or a frame and the first frame, differ in
    size; FormatError if there is no pair.

    Shapes
    ------
    each item: (name, left (H, W, 3) uint8, right (H, W, 3) uint8).
    """

    def __init__(self, pairs: list[tuple[str, str, str]], fps: float = DEFAULT_FPS):
        if not pairs:
            raise FormatError("an image sequence needs at least one pair of images")
        self.pairs = list(pairs)
        self.count, self.fps = len(self.pairs), float(fps)
        self.stem = Path(self.pairs[0][0]).parent.name or "sequence"

    def __iter__(self) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
        first = None
        for left_path, right_path, name in self.pairs:
            left, right = read_image(left_path), read_image(right_path)
            if left.shape != right.shape:
                raise ShapeError(f"{left_path} is {left.shape[0]}x{left.shape[1]} (HxW) but {right_path} is "
                                 f"{right.shape[0]}x{right.shape[1]}: the two images of a pair must have one size")
            first = left.shape if first is None else first
            if left.shape != first:
                raise ShapeError(f"{left_path} is {left.shape[0]}x{left.shape[1]} (HxW) but the sequence's first frame "
                                 f"is {first[0]}x{first[1]}: the frames of a sequence must have one size")
            yield name, left, right


def pooled_percentiles(arrays: Callable[[], Iterable[np.ndarray]], percentiles: tuple[float, float] = (1.0, 99.0),
                       bins: int = HISTOGRAM_BINS) -> tuple[float, float]:
    """Percentiles of the finite values of many arrays together, without holding them all: one pass for the
    extent, one for a histogram of ``bins`` bins over it; each percentile is the upper edge of the bin where the
    cumulative count reaches it (exact to the bin width, ``(max - min) / bins``).

    ``arrays`` is called once per pass and returns the arrays (e.g. read back from the saved ``.npy`` files).
    ArgumentError if no array holds a finite value.
    """
    low, high = np.inf, -np.inf
    for array in arrays():
        values = np.asarray(array, dtype=np.float64)
        finite = values[np.isfinite(values)]
        if finite.size:
            low, high = min(low, float(finite.min())), max(high, float(finite.max()))
    if not np.isfinite(low):
        raise ArgumentError("pooled_percentiles: no finite value in any array")
    if low == high:
        return low, high
    counts = np.zeros(bins, dtype=np.int64)
    for array in arrays():
        values = np.asarray(array, dtype=np.float64)
        counts += np.histogram(values[np.isfinite(values)], bins=bins, range=(low, high))[0]
    cumulative = np.cumsum(counts)
    edges = np.linspace(low, high, bins + 1)
    # the first bin whose cumulative count reaches p% of all values; its upper edge is the percentile
    found = [edges[int(np.searchsorted(cumulative, p / 100.0 * cumulative[-1], side="left")) + 1] for p in percentiles]
    return float(found[0]), float(found[1])


class DisparityVideo:
    """An H.264 mp4 of colourised disparities of one size, every frame in one colour range (turbo, :func:`colorize`),
    written atomically (the file appears when the ``with`` block ends without an error). Frames of odd height or width
    are padded by one replicated row or column (H.264's 4:2:0 needs even sizes). The range goes into the ``comment``
    metadata (:func:`read_colour_range`).

    Use as a context manager: ``with DisparityVideo(path, fps, (H, W), vmin, vmax) as video: video.write(disp)``.
    """

    def __init__(self, path: str, fps: float, size: tuple[int, int], vmin: float, vmax: float):
        if not vmin < vmax:
            raise ArgumentError(f"DisparityVideo: the colour range needs vmin < vmax, got {vmin}, {vmax}")
        self.path, self.fps, self.size = str(path), float(fps), (int(size[0]), int(size[1]))
        self.vmin, self.vmax = float(vmin), float(vmax)
        self.frames = 0

    def __enter__(self) -> "DisparityVideo":
        av = _av()
        self._writing = atomic_write(self.path)
        file = self._writing.__enter__()
        try:
            self._container = av.open(file, "w", format="mp4")
            self._container.metadata["comment"] = json.dumps({"vmin": self.vmin, "vmax": self.vmax,
                                                              "colormap": "turbo"})
            self._stream = self._container.add_stream(_CODEC, rate=Fraction(self.fps).limit_denominator(1001))
            # even sizes: H + H mod 2, W + W mod 2
            self._stream.height, self._stream.width = (side + side % 2 for side in self.size)
            self._stream.pix_fmt = _PIXEL_FORMAT
            self._stream.options = {"crf": _QUALITY}
        except BaseException as failure:  # no video: the atomic writer drops the temporary file
            self._writing.__exit__(type(failure), failure, failure.__traceback__)
            raise
        return self

    def write(self, disparity: np.ndarray) -> None:
        """Appends one frame: ``disparity`` (H, W) coloured in the video's range (non-finite values black)."""
        av = _av()
        if np.shape(disparity) != self.size:
            raise ShapeError(f"{self.path}: frame {self.frames} is {list(np.shape(disparity))}, the video's frames "
                             f"{self.size[0]}x{self.size[1]} (HxW)")
        image = colorize(disparity, vmin=self.vmin, vmax=self.vmax)
        # pad to even sizes: one replicated row / column where H / W is odd
        image = np.pad(image, ((0, image.shape[0] % 2), (0, image.shape[1] % 2), (0, 0)), mode="edge")
        for packet in self._stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")):
            self._container.mux(packet)
        self.frames += 1

    def __exit__(self, kind, error, trace) -> None:
        try:
            if kind is None:
                for packet in self._stream.encode():  # flush the encoder
                    self._container.mux(packet)
            self._container.close()
        except BaseException as failure:  # the file is not whole: the atomic writer drops it
            self._writing.__exit__(type(failure), failure, failure.__traceback__)
            raise
        self._writing.__exit__(kind, error, trace)


def read_colour_range(path: str) -> tuple[float, float]:
    """The (vmin, vmax) a :class:`DisparityVideo` stored in its metadata; FormatError if it has none."""
    video = _Video(str(path))
    try:
        comment = video.container.metadata.get("comment")
        stored = json.loads(comment) if comment else None
        if not isinstance(stored, dict) or "vmin" not in stored or "vmax" not in stored:
            raise FormatError(f"{path}: no mipnet colour range in the video's metadata")
        return float(stored["vmin"]), float(stored["vmax"])
    except json.JSONDecodeError:
        raise FormatError(f"{path}: the video's comment metadata is not mipnet's colour range") from None
    finally:
        video.container.close()
