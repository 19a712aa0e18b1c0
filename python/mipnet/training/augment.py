"""Training augmentations of architecture.md §3.3: RAFT-Stereo's ``FlowAugmentor`` / ``SparseFlowAugmentor``
with a CREStereo-like occlusion patch.

An augmentor is a DataLoader transform, ``aug(sample, rng) -> sample``: every random choice comes
from the ``numpy.random.Generator`` it is given (the loader seeds one per sample from
(seed, epoch, position)), so a run is reproducible. The steps, in the order of architecture.md §3.3:

1. photometric: ColorJitter (brightness, contrast, saturation, hue in a random order, as
   torchvision on PIL images) then gamma; independent draws for the two views with probability
   ``asymmetric_prob``, else one draw for the vertically stacked pair;
2. occluders on the right image: the eraser (1-2 rectangles filled with the right image's mean
   colour) and the occlusion patch (a rectangle of the right image copied over another place);
3. spatial: resize by (s_y, s_x) with bilinear half-pixel-centre sampling (``cv2.INTER_LINEAR``)
   and the disparity multiplied by s_x (dense), or a nearest scatter of the valid ground-truth
   pixels (sparse);
4. the crop, the right one shifted vertically by ``delta`` px (``yjitter``, dense only);
5. optionally (``veil_prob``, off by default, not in RAFT) a veil: a band of rows faded towards one
   pale colour in both views alike. Rows are epipolar lines, so the veil covers the same scene points
   in both views whatever their depth; it is there so that "pale and weakly textured" stops meaning
   "far" (as it does under water, where haze grows with range), e.g. a pale near floor in air;
6. optionally (``noise_prob``, off by default, not in RAFT) dim light and sensor noise on the crop: the
   linear image under a random illumination (uniform, or a spot light that fades towards the edges,
   the same in both views) and a random exposure, then Poisson shot noise and Gaussian read noise drawn
   independently for each view, as :func:`mipnet.underwater.degrade`'s sensor. Dark, noisy regions then
   occur at every depth and on every kind of scene; it is there to make the network match through the
   noise of a low-light image. Measured so far (docs/training.md, stages 9 and 10): on every source,
   better in air and on the real pairs, worse under water, where dark does mean far; on the pairs in air
   only (``TrainConfig.noise_sources``), worse under water still.

Speed: every draw is made before any pixel is touched, so only the source window that the crop
reads is coloured, occluded and resampled, which gives exactly the pixels of "whole image, then
crop" for the pointwise steps. The two statistics of the pipeline are therefore taken over that
window (the region the crop sees) instead of the whole image: the contrast pivot (mean grey) and
the eraser's fill colour. :meth:`StereoAugmentor.draw` returns every draw as an
:class:`AugmentParams` and :meth:`StereoAugmentor.apply` applies them, so a test or a debugging
session can see what was done.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
from PIL import Image, ImageEnhance, ImageStat

from ..errors import ArgumentError, DTypeError, ShapeError
from ..random import log_uniform
from ..underwater.color import linear_to_srgb, srgb_to_linear

__all__ = ["AugmentParams", "ColorParams", "VeilParams", "NoiseParams", "StereoAugmentor", "SparseStereoAugmentor", "make_augmentor"]

#: Occluder sides are scaled by min(1, shorter image side / this) (RAFT's 50-99 px suit >= 384 px images).
OCCLUDER_REFERENCE_SIDE = 384

_BRIGHTNESS, _CONTRAST, _SATURATION, _HUE = range(4)


@dataclass(frozen=True)
class ColorParams:
    """One photometric draw: ColorJitter factors, the order they are applied in, and gamma.

    ``order`` is a permutation of (0 brightness, 1 contrast, 2 saturation, 3 hue); the enhance
    factors are 1 for identity, ``hue`` is a fraction of the hue circle in [-0.5, 0.5], and the
    gamma step maps v to 255 * gain * (v / 255) ** gamma.
    """

    order: tuple[int, ...]
    brightness: float
    contrast: float
    saturation: float
    hue: float
    gamma: float
    gain: float


@dataclass(frozen=True)
class VeilParams:
    """A band of rows faded towards one colour: ``pixel = (1 - a(y)) pixel + a(y) colour``.

    ``a(y) = strength`` for source rows ``top <= y <= bottom`` and falls to 0 over ``soft`` rows
    on either side along a raised cosine. Applied to both views at the same source rows.
    """

    top: float
    bottom: float
    soft: float
    strength: float
    colour: tuple[float, float, float]

    def alpha(self, rows: np.ndarray) -> np.ndarray:
        """a(y) at source rows ``rows``, shape of ``rows``."""
        # rows outside [top, bottom]: distance to the band, 0 inside it
        outside = np.maximum(np.maximum(self.top - rows, rows - self.bottom), 0.0)
        # raised cosine from 1 at the band's edge to 0 at soft rows from it
        return self.strength * 0.5 * (1.0 + np.cos(np.pi * np.minimum(outside / self.soft, 1.0)))

    def apply(self, image: np.ndarray, first_row: int) -> np.ndarray:
        """The veiled copy of ``image`` whose row 0 is source row ``first_row``.

        Shapes
        ------
        image: (h, w, 3) uint8 -> (h, w, 3) uint8.
        """
        # image row i is source row first_row + i
        a = self.alpha(first_row + np.arange(image.shape[0], dtype=np.float32)).astype(np.float32)[:, None, None]
        veiled = image * (1.0 - a) + a * np.asarray(self.colour, dtype=np.float32)
        return np.clip(np.rint(veiled), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class NoiseParams:
    """Dim light and sensor noise on the output crop (step 6), both views alike but for the noise draws.

    Linear output = ``Poisson(L * light(y, x) * exposure * full_well) / full_well + N(0, read_noise)``,
    with L the crop's linear (sRGB-decoded) value; ``light = floor + (1 - floor) exp(-(r / radius)^2)``,
    r the distance from ``centre`` (crop rows, columns) over the crop's diagonal (``floor`` = 1: uniform).
    The noise of view v (0 left, 1 right) comes from ``numpy.random.default_rng([seed, v])``.
    """

    exposure: float
    full_well: float
    read_noise: float
    floor: float
    centre: tuple[float, float]
    radius: float
    seed: int

    def light(self, height: int, width: int) -> np.ndarray:
        """The illumination over an (height, width) crop, shape (height, width, 1)."""
        rows = np.arange(height, dtype=np.float32)[:, None] - self.centre[0]
        cols = np.arange(width, dtype=np.float32)[None, :] - self.centre[1]
        # squared distance to the centre as a fraction of the diagonal
        r2 = (rows**2 + cols**2) / np.float32(height**2 + width**2)
        spot = np.exp(-r2 / np.float32(self.radius**2))
        return (self.floor + (1.0 - self.floor) * spot)[..., None].astype(np.float32)

    def apply(self, image: np.ndarray, view: int) -> np.ndarray:
        """The dimmed, noisy copy of crop ``image`` as seen by view ``view`` (0 left, 1 right).

        Shapes
        ------
        image: (h, w, 3) uint8 -> (h, w, 3) uint8.
        """
        rng = np.random.default_rng([self.seed, view])
        signal = srgb_to_linear(image) * self.light(*image.shape[:2]) * np.float32(self.exposure * self.full_well)
        electrons = rng.poisson(signal).astype(np.float32)
        noisy = electrons / np.float32(self.full_well) + rng.normal(0.0, self.read_noise, image.shape).astype(np.float32)
        return linear_to_srgb(noisy)


@dataclass(frozen=True)
class AugmentParams:
    """Every random draw of one augmentation, in the input image's coordinates unless stated.

    Attributes
    ----------
    color : tuple of ColorParams
        Empty: no photometric step; one: applied to the stacked pair; two: (left, right).
    erase : tuple of (y, x, h, w)
        Eraser rectangles on the right image (clipped to the image).
    patch : (src_y, src_x, dst_y, dst_x, h, w) or None
        Occlusion patch: the right image's ``[src_y:src_y+h, src_x:src_x+w]`` is copied to ``dst``.
    scale : (s_y, s_x)
        Resize factors; (1, 1) is no resize.
    size : (H', W')
        Resized image size, ``rint(H * s_y), rint(W * s_x)`` as ``cv2.resize(fx=s_x, fy=s_y)``.
    origin : (y0, x0)
        Crop origin in the resized left image.
    delta : int
        The right crop starts at row ``y0 + delta`` (y-jitter).
    veil : VeilParams or None
        Step 5, in input rows; None: no veil.
    noise : NoiseParams or None
        Step 6, in crop coordinates; None: no dimming or noise.
    """

    color: tuple[ColorParams, ...]
    erase: tuple[tuple[int, int, int, int], ...]
    patch: tuple[int, int, int, int, int, int] | None
    scale: tuple[float, float]
    size: tuple[int, int]
    origin: tuple[int, int]
    delta: int
    veil: VeilParams | None = None
    noise: NoiseParams | None = None


def _resize_taps(size_in: int, scale: float, start: int, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source taps of output indices ``start .. start+count-1`` of a linear resize by ``scale``.

    Returns (i0, i1, w): output o = (1 - w) * src[i0] + w * src[i1].

    Shapes
    ------
    i0, i1, w: (count,).
    """
    out = np.arange(start, start + count, dtype=np.float64)
    # half-pixel centres (cv2.INTER_LINEAR, torch align_corners=False): output o samples (o + 0.5) / s - 0.5
    src = np.maximum((out + 0.5) / scale - 0.5, 0.0)
    # i0 = floor(src), kept inside the image; past the last centre the last pixel repeats (w = 0)
    i0 = np.minimum(np.floor(src).astype(np.intp), size_in - 1)
    w = np.where(i0 < size_in - 1, src - i0, 0.0).astype(np.float32)
    # right neighbour where it has weight, else i0 itself, so the taps read only contributing pixels
    i1 = np.where(w > 0, i0 + 1, i0)
    return i0, i1, w


def _blend_axis(array: np.ndarray, taps: tuple[np.ndarray, np.ndarray, np.ndarray], axis: int) -> np.ndarray:
    """One separable pass of :func:`_resample` along ``axis`` (float32 blend, or AND for bool).

    Shapes
    ------
    array: (..., n_in along axis, ...) -> (..., len(taps[0]), ...).
    """
    i0, i1, w = taps
    if not w.any() and i0[-1] - i0[0] == len(i0) - 1 and np.all(np.diff(i0) == 1):
        # identity taps (scale 1): the output is a slice of the input
        index = [slice(None)] * array.ndim
        index[axis] = slice(int(i0[0]), int(i0[0]) + len(i0))
        return array[tuple(index)]
    shape = [1] * array.ndim
    shape[axis] = -1
    w = w.reshape(shape)
    first, second = np.take(array, i0, axis=axis), np.take(array, i1, axis=axis)
    if array.dtype == bool:
        # valid iff every tap with non-zero weight is valid (i0 always has weight 1 - w > 0)
        return first & (second | (w == 0))
    first = first.astype(np.float32, copy=False)
    # first + (second - first) * w, in place on the fresh copy of second
    out = second.astype(np.float32, copy=True)
    out -= first
    out *= w
    out += first
    return out


def _span(taps: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[int, int]:
    """Source index range [first i0, max i1 + 1) read by monotonic taps."""
    return int(taps[0][0]), int(taps[1].max()) + 1


def _shift_taps(taps: tuple[np.ndarray, np.ndarray, np.ndarray], offset: int):
    """The same taps in a window starting at source index ``offset``: i - offset."""
    return taps[0] - offset, taps[1] - offset, taps[2]


def _resample(array: np.ndarray, rows: tuple, cols: tuple) -> np.ndarray:
    """Bilinear resize (``cv2.INTER_LINEAR`` semantics) restricted to the output pixels whose taps
    are ``rows`` x ``cols`` (from :func:`_resize_taps`); the one resize of images, disparity and masks.

    uint8 images are rounded back to uint8, float32 stays float32, and a bool mask is True only
    where every source pixel with a non-zero weight is True.

    Shapes
    ------
    array: (H, W) or (H, W, C) -> (len(rows[0]), len(cols[0])) or (..., C).
    """
    (y_lo, y_hi), (x_lo, x_hi) = _span(rows), _span(cols)
    window = array[y_lo:y_hi, x_lo:x_hi]
    out = _blend_axis(_blend_axis(window, _shift_taps(rows, y_lo), 0), _shift_taps(cols, x_lo), 1)
    if array.dtype == np.uint8 and out.dtype != np.uint8:
        # a convex combination of values in [0, 255] rounds back into [0, 255]
        out = np.rint(out).astype(np.uint8)
    elif out.dtype != array.dtype:
        out = out.astype(array.dtype)
    if np.may_share_memory(out, array):
        # identity taps gave a view: never hand out (or later modify) the caller's array
        return out.copy()
    return np.ascontiguousarray(out)


def _jitter_range(value, name: str, owner: str, centre: float = 1.0, bound: tuple[float, float] = (0.0, math.inf)):
    """torchvision ``ColorJitter._check_input``: a number v means [centre - v, centre + v] (clipped
    at ``bound[0]``), a pair is taken as the range itself."""
    if isinstance(value, Real):
        if value < 0:
            raise ArgumentError(f"{owner}: {name} must be >= 0, got {value}")
        low, high = max(bound[0], centre - value), centre + value
    else:
        low, high = _float_pair(value, name, owner)
    if not bound[0] <= low <= high <= bound[1]:
        raise ArgumentError(f"{owner}: {name} range must satisfy {bound[0]} <= low <= high <= {bound[1]}, "
                            f"got ({low}, {high})")
    return float(low), float(high)


def _float_pair(value, name: str, owner: str) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ArgumentError(f"{owner}: {name} must be a number or a pair of numbers, got {value!r}") from None
    return low, high


def _check_pair(value, name: str, owner: str, positive: bool = False) -> tuple[int, int]:
    try:
        a, b = value
    except (TypeError, ValueError):
        raise ArgumentError(f"{owner}: {name} must be a pair of ints, got {value!r}") from None
    if not (isinstance(a, Integral) and isinstance(b, Integral)) or (positive and (a <= 0 or b <= 0)):
        kind = "positive ints" if positive else "ints"
        raise ArgumentError(f"{owner}: {name} must be two {kind}, got {value!r}")
    return int(a), int(b)


def _check_prob(value: float, name: str, owner: str) -> float:
    if not 0.0 <= value <= 1.0:
        raise ArgumentError(f"{owner}: {name} must be a probability in [0, 1], got {value}")
    return float(value)


def _apply_color(image: np.ndarray, p: ColorParams, pivot: int | None = None) -> tuple[np.ndarray, int | None]:
    """ColorJitter + gamma on a uint8 RGB image, with torchvision's PIL semantics (each step rounds to uint8).

    ``pivot`` is the contrast step's grey level; None computes it as PIL ``ImageEnhance.Contrast``
    does (rounded mean of the L image at that point of the chain). It is returned, so another
    region of the same view can get the identical transform.

    Shapes
    ------
    image: (H, W, 3) -> (H, W, 3).
    """
    pil = Image.fromarray(image)
    for op in p.order:
        if op == _BRIGHTNESS and p.brightness != 1.0:
            pil = ImageEnhance.Brightness(pil).enhance(p.brightness)
        elif op == _CONTRAST and p.contrast != 1.0:
            if pivot is None:
                pivot = int(ImageStat.Stat(pil.convert("L")).mean[0] + 0.5)
            pil = Image.blend(Image.new("RGB", pil.size, (pivot,) * 3), pil, p.contrast)
        elif op == _SATURATION and p.saturation != 1.0:
            pil = ImageEnhance.Color(pil).enhance(p.saturation)
        elif op == _HUE and p.hue != 0.0:
            hue, sat, val = pil.convert("HSV").split()
            # PIL's hue is 0..255 around the circle; torchvision shifts it by int(h * 255), wrapping
            shift = int(p.hue * 255) % 256
            hue = hue.point([(level + shift) % 256 for level in range(256)])
            pil = Image.merge("HSV", (hue, sat, val)).convert("RGB")
    if p.gamma != 1.0 or p.gain != 1.0:
        # torchvision adjust_gamma (PIL): v -> int(255.999 * gain * (v / 255) ** gamma), clipped by PIL
        lut = [min(255, int((255 + 1 - 1e-3) * p.gain * (level / 255.0) ** p.gamma)) for level in range(256)]
        pil = pil.point(lut * 3)
    return np.array(pil), pivot


def _crop_origin(rng: np.random.Generator, slack: int, margin: int) -> int:
    """Crop origin in U{m, max(m, slack - m - 1)} with m = min(margin, slack // 2): RAFT's
    U{2, slack - 3} for margin 2, kept inside the image when the slack is small."""
    m = min(margin, slack // 2)
    return int(rng.integers(m, max(m, slack - m - 1), endpoint=True))


def _erase(image: np.ndarray, origin: tuple[int, int], rectangles, fill) -> None:
    """Fill the eraser ``rectangles`` (y, x, h, w, image coordinates) on ``image``, a region whose
    top-left pixel is ``origin`` of the image, in place.

    Shapes
    ------
    image: (h, w, 3); fill: (3,).
    """
    oy, ox = origin
    for y, x, h, w in rectangles:
        # rectangle rows y .. y+h-1 in region coordinates, clipped to the region
        top, bottom = max(y - oy, 0), min(y + h - oy, image.shape[0])
        first, last = max(x - ox, 0), min(x + w - ox, image.shape[1])
        if top < bottom and first < last:
            image[top:bottom, first:last] = fill


def _margin_origin(rng: np.random.Generator, slack: int, before: int, after: int) -> int:
    """RAFT's sparse crop origin: U{-before, slack + after - 1} clipped to [0, slack], so the crop
    touches the image border with extra probability."""
    if slack + before + after <= 0:
        return 0
    return min(max(int(rng.integers(-before, slack + after)), 0), slack)


class StereoAugmentor:
    """The dense-ground-truth augmentation of architecture.md §3.3 (RAFT-Stereo ``FlowAugmentor`` with ``yjitter``).

    Parameters
    ----------
    crop : (int, int)
        Output size (crop_h, crop_w).
    photometric : bool
        Colour jitter and gamma on (step 1).
    brightness, contrast : float or (float, float)
        ColorJitter: a number v draws the factor from U(max(0, 1 - v), 1 + v). Defaults 0.4.
    saturation : float or (float, float)
        Default (0.0, 1.4) (RAFT-Stereo's training command, the paper's "between 0 and 1.4").
    hue : float or (float, float)
        Hue shift as a fraction of the circle, U(-v, v) for a number v <= 0.5. Default 0.5 / 3.14.
    gamma, gain : (float, float)
        Gamma and gain of ``adjust_gamma``, drawn uniformly; default (1, 1) each, the identity.
    asymmetric_prob : float
        Probability of independent draws for the two views (default 0.2); otherwise one draw is
        applied to the vertically stacked pair, so both views share even the contrast pivot
        (the mean grey of the source regions the two crops read).
    eraser_prob : float
        Probability (default 0.5) of 1 or 2 (equally likely) rectangles on the right image with
        sides U{eraser_size}, top-left corner anywhere in the image (clipped at its border),
        filled with the mean colour, after step 1, of the right-image region the crop reads.
    eraser_size : (int, int)
        Side range in px, inclusive, default (50, 99) (RAFT's ``randint(50, 100)``); scaled by
        min(1, min(H, W) / :data:`OCCLUDER_REFERENCE_SIDE`) for small images (at least 1 px).
    patch_prob : float
        Probability (default 0.5) of the occlusion patch: a rectangle of the right image, sides as
        the eraser's, copied from one place of that image to another (CREStereo-like occlusion:
        the pasted texture matches nothing in the left image). Applied after the eraser.
    spatial : bool
        Scale and stretch on (step 3). When off, or not drawn, images smaller than the crop are
        still upscaled by the clamp below, so every image gives a full crop.
    spatial_prob : float
        Probability of the resize when ``spatial`` (default 1.0, RAFT's value for dense GT).
    scale_range : (float, float)
        log2 of the scale: s = 2 ** U(scale_range), default (-0.2, 0.4).
    stretch_prob, max_stretch : float
        With probability ``stretch_prob`` (0.8) s_x = s * 2 ** U(-m, m) and s_y = s * 2 ** U(-m, m)
        independently, m = ``max_stretch`` (0.2). Both are then clamped to
        >= max((crop_h + 8) / H, (crop_w + 8) / W).
    yjitter : int
        Maximum |delta| of the right crop's row offset (default 2; 0 disables). Crop origins are
        y0 ~ U{2, H' - crop_h - 3} and x0 ~ U{2, W' - crop_w - 3}, margins shrunk when the resized
        image is only just larger than the crop.
    max_disparity : float or None
        After augmentation ``valid &= |d| < max_disparity`` (default 512, RAFT's rule); None: off.
    veil_prob : float
        Probability of the veil (step 5; default 0, RAFT has none): a band of 15-70% of the input's
        rows, starting anywhere from 30% above the image to 90% down it, with soft edges of 5-30% of
        the height, faded by 50-92% towards a grey of 35-95% with a slight tint. No draw is made
        when it is 0, so runs without it see exactly the augmentation they saw before it existed.
    noise_prob : float
        Probability of dim light and sensor noise (step 6; default 0, RAFT has none): exposure
        logU(0.1, 1), full well logU(50, 3000) electrons, read noise logU(0.001, 0.015) of full scale;
        half of the time uniform light, else a spot centred anywhere in the crop with radius
        U(0.3, 0.8) of the diagonal over a floor logU(0.05, 0.5). No draw is made when it is 0.

    Notes
    -----
    Input disparity that is not finite is made invalid (and 0) before resizing. The disparity at
    invalid output pixels is resampled like any other and is meaningful only where the input's
    was. Keys other than ``left``, ``right``, ``disparity`` and ``valid`` pass through unchanged.
    There are no flips (RAFT-Stereo ``do_flip=False`` for stereo).

    Shapes
    ------
    sample: left, right (H, W, 3) uint8; disparity (H, W) float; valid (H, W) bool ->
    left, right (crop_h, crop_w, 3) uint8; disparity (crop_h, crop_w) float32; valid (crop_h, crop_w) bool.

    Raises
    ------
    ArgumentError
        A crop or range that makes no sense (at construction), a sample without those keys.
    ShapeError
        Images or maps whose shapes disagree, or images that are not (H, W, 3).
    DTypeError
        Images that are not uint8.
    """

    #: margin the scale clamp keeps around the crop, (crop + margin) / size (RAFT: 8 dense, 1 sparse)
    _clamp_margin = 8

    def __init__(self, crop: tuple[int, int], *, photometric: bool = True, brightness=0.4, contrast=0.4,
                 saturation=(0.0, 1.4), hue=0.5 / 3.14, gamma=(1.0, 1.0), gain=(1.0, 1.0),
                 asymmetric_prob: float = 0.2, eraser_prob: float = 0.5, eraser_size: tuple[int, int] = (50, 99),
                 patch_prob: float = 0.5, spatial: bool = True, spatial_prob: float = 1.0,
                 scale_range: tuple[float, float] = (-0.2, 0.4), stretch_prob: float = 0.8,
                 max_stretch: float = 0.2, yjitter: int = 2, max_disparity: float | None = 512.0,
                 veil_prob: float = 0.0, noise_prob: float = 0.0):
        owner = type(self).__name__
        self.crop = _check_pair(crop, "crop", owner, positive=True)
        self.photometric = bool(photometric)
        self.brightness = _jitter_range(brightness, "brightness", owner)
        self.contrast = _jitter_range(contrast, "contrast", owner)
        self.saturation = _jitter_range(saturation, "saturation", owner)
        self.hue = _jitter_range(hue, "hue", owner, centre=0.0, bound=(-0.5, 0.5))
        self.gamma = _jitter_range(gamma, "gamma", owner, bound=(1e-6, math.inf))
        self.gain = _jitter_range(gain, "gain", owner)
        self.asymmetric_prob = _check_prob(asymmetric_prob, "asymmetric_prob", owner)
        self.eraser_prob = _check_prob(eraser_prob, "eraser_prob", owner)
        self.eraser_size = _check_pair(eraser_size, "eraser_size", owner, positive=True)
        if self.eraser_size[0] > self.eraser_size[1]:
            raise ArgumentError(f"{owner}: eraser_size must be (low, high) with low <= high, got {eraser_size}")
        self.patch_prob = _check_prob(patch_prob, "patch_prob", owner)
        self.spatial = bool(spatial)
        self.spatial_prob = _check_prob(spatial_prob, "spatial_prob", owner)
        low, high = _float_pair(scale_range, "scale_range", owner)
        if not low <= high:
            raise ArgumentError(f"{owner}: scale_range must be (low, high) with low <= high, got {scale_range}")
        self.scale_range = (low, high)
        self.stretch_prob = _check_prob(stretch_prob, "stretch_prob", owner)
        if max_stretch < 0:
            raise ArgumentError(f"{owner}: max_stretch must be >= 0, got {max_stretch}")
        self.max_stretch = float(max_stretch)
        if not isinstance(yjitter, Integral) or yjitter < 0:
            raise ArgumentError(f"{owner}: yjitter must be an int >= 0, got {yjitter!r}")
        self.yjitter = int(yjitter)
        if max_disparity is not None and not max_disparity > 0:
            raise ArgumentError(f"{owner}: max_disparity must be > 0 or None, got {max_disparity}")
        self.max_disparity = None if max_disparity is None else float(max_disparity)
        self.veil_prob = _check_prob(veil_prob, "veil_prob", owner)
        self.noise_prob = _check_prob(noise_prob, "noise_prob", owner)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(crop={self.crop}, photometric={self.photometric}, spatial={self.spatial}, "
                f"eraser_prob={self.eraser_prob}, patch_prob={self.patch_prob}, yjitter={self.yjitter}, "
                f"veil_prob={self.veil_prob}, noise_prob={self.noise_prob})")

    def __call__(self, sample: dict, rng: np.random.Generator) -> dict:
        """Augment one sample with draws from ``rng`` (``apply(sample, draw(shape, rng))``).

        Shapes
        ------
        See the class docstring.
        """
        self._check_sample(sample)
        return self.apply(sample, self.draw(sample["left"].shape[:2], rng))

    def _check_sample(self, sample: dict) -> None:
        owner = f"{type(self).__name__}.__call__"
        missing = [k for k in ("left", "right", "disparity", "valid") if k not in sample]
        if missing:
            raise ArgumentError(f"{owner}: sample lacks {missing} (has {sorted(sample)})")
        left, right = np.asarray(sample["left"]), np.asarray(sample["right"])
        disparity, valid = np.asarray(sample["disparity"]), np.asarray(sample["valid"])
        if left.ndim != 3 or left.shape[2] != 3 or right.shape != left.shape:
            raise ShapeError(f"{owner}: left and right must both be (H, W, 3), got left={list(left.shape)} "
                             f"right={list(right.shape)}")
        if disparity.shape != left.shape[:2] or valid.shape != left.shape[:2]:
            raise ShapeError(f"{owner}: disparity and valid must be (H, W) = {list(left.shape[:2])}, got "
                             f"disparity={list(disparity.shape)} valid={list(valid.shape)}")
        if left.dtype != np.uint8 or right.dtype != np.uint8:
            raise DTypeError(f"{owner}: images must be uint8, got left {left.dtype} right {right.dtype} "
                             f"with shape {list(left.shape)}")
        if not np.issubdtype(disparity.dtype, np.floating):
            raise DTypeError(f"{owner}: disparity must be float, got {disparity.dtype} "
                             f"with shape {list(disparity.shape)}")
        if left.shape[0] < 1 or left.shape[1] < 1:
            raise ShapeError(f"{owner}: images must be at least 1x1, got {list(left.shape)}")

    # ----------------------------------------------------------------------------------- draws

    def draw(self, shape: tuple[int, int], rng: np.random.Generator) -> AugmentParams:
        """Draw every random choice for an input of ``shape`` = (H, W).

        Returns
        -------
        AugmentParams
        """
        height, width = _check_pair(shape, "shape", f"{type(self).__name__}.draw", positive=True)
        color = self._draw_color(rng)
        erase, patch = self._draw_occluders(height, width, rng)
        scale, size, origin, delta = self._draw_geometry(height, width, rng)
        veil = self._draw_veil(height, rng) if self.veil_prob > 0 else None
        noise = self._draw_noise(rng) if self.noise_prob > 0 else None
        return AugmentParams(color=color, erase=erase, patch=patch, scale=scale, size=size, origin=origin, delta=delta,
                             veil=veil, noise=noise)

    def _draw_noise(self, rng: np.random.Generator) -> NoiseParams | None:
        if rng.random() >= self.noise_prob:
            return None
        exposure, full_well = log_uniform(rng, 0.1, 1.0), log_uniform(rng, 50.0, 3000.0)
        read_noise = log_uniform(rng, 0.001, 0.015)
        uniform = rng.random() < 0.5
        floor, radius = (1.0 if uniform else log_uniform(rng, 0.05, 0.5)), float(rng.uniform(0.3, 0.8))
        centre = (float(rng.uniform(0, self.crop[0])), float(rng.uniform(0, self.crop[1])))
        return NoiseParams(exposure=exposure, full_well=full_well, read_noise=read_noise, floor=floor, centre=centre,
                           radius=radius, seed=int(rng.integers(2**62)))

    def _draw_veil(self, height: int, rng: np.random.Generator) -> VeilParams | None:
        if rng.random() >= self.veil_prob:
            return None
        top = rng.uniform(-0.3, 0.9) * height
        bottom = top + rng.uniform(0.15, 0.7) * height
        soft = rng.uniform(0.05, 0.3) * height
        grey = rng.uniform(0.35, 0.95) * 255.0
        colour = np.clip(grey + rng.uniform(-0.05, 0.05, 3) * 255.0, 0.0, 255.0)
        return VeilParams(top=float(top), bottom=float(bottom), soft=float(soft), strength=float(rng.uniform(0.5, 0.92)),
                          colour=tuple(float(c) for c in colour))

    def _draw_color_once(self, rng: np.random.Generator) -> ColorParams:
        order = tuple(int(i) for i in rng.permutation(4))
        b, c, s, h, g, k = (float(rng.uniform(*r)) for r in
                            (self.brightness, self.contrast, self.saturation, self.hue, self.gamma, self.gain))
        return ColorParams(order=order, brightness=b, contrast=c, saturation=s, hue=h, gamma=g, gain=k)

    def _draw_color(self, rng: np.random.Generator) -> tuple[ColorParams, ...]:
        if not self.photometric:
            return ()
        if rng.random() < self.asymmetric_prob:
            return (self._draw_color_once(rng), self._draw_color_once(rng))
        return (self._draw_color_once(rng),)

    def _occluder_sides(self, height: int, width: int) -> tuple[int, int]:
        factor = min(1.0, min(height, width) / OCCLUDER_REFERENCE_SIDE)
        low = max(1, round(self.eraser_size[0] * factor))
        return low, max(low, round(self.eraser_size[1] * factor))

    def _draw_occluders(self, height: int, width: int, rng: np.random.Generator):
        low, high = self._occluder_sides(height, width)
        erase = []
        if rng.random() < self.eraser_prob:
            for _ in range(int(rng.integers(1, 2, endpoint=True))):
                # RAFT: top-left corner anywhere in the image, the rectangle clipped at the border
                y, x = int(rng.integers(0, height)), int(rng.integers(0, width))
                h, w = int(rng.integers(low, high, endpoint=True)), int(rng.integers(low, high, endpoint=True))
                erase.append((y, x, h, w))
        patch = None
        if rng.random() < self.patch_prob:
            h = min(height, int(rng.integers(low, high, endpoint=True)))
            w = min(width, int(rng.integers(low, high, endpoint=True)))
            # source and destination corners keep the whole h x w patch inside the image
            sy, dy = (int(v) for v in rng.integers(0, height - h, size=2, endpoint=True))
            sx, dx = (int(v) for v in rng.integers(0, width - w, size=2, endpoint=True))
            patch = (sy, sx, dy, dx, h, w)
        return tuple(erase), patch

    def _min_scale(self, height: int, width: int) -> float:
        # RAFT clamp: the resized image exceeds the crop by the margin on both axes
        return max((self.crop[0] + self._clamp_margin) / height, (self.crop[1] + self._clamp_margin) / width)

    def _draw_scale(self, height: int, width: int, rng: np.random.Generator) -> tuple[float, float]:
        min_scale = self._min_scale(height, width)
        if self.spatial and rng.random() < self.spatial_prob:
            s = 2.0 ** rng.uniform(*self.scale_range)
            s_y = s_x = s
            if rng.random() < self.stretch_prob:
                # independent stretches of both axes, s * 2**U(-m, m)
                s_x = s * 2.0 ** rng.uniform(-self.max_stretch, self.max_stretch)
                s_y = s * 2.0 ** rng.uniform(-self.max_stretch, self.max_stretch)
            return max(float(s_y), min_scale), max(float(s_x), min_scale)
        if height < self.crop[0] or width < self.crop[1]:
            # too small for the crop without the spatial step: the clamp's uniform upscale
            return min_scale, min_scale
        return 1.0, 1.0

    def _draw_geometry(self, height: int, width: int, rng: np.random.Generator):
        s_y, s_x = self._draw_scale(height, width, rng)
        # cv2.resize(fx=s_x, fy=s_y) output size: rint(W * s_x), rint(H * s_y)
        size = (int(np.rint(height * s_y)), int(np.rint(width * s_x)))
        slack_y, slack_x = size[0] - self.crop[0], size[1] - self.crop[1]
        y0 = _crop_origin(rng, slack_y, self.yjitter)
        x0 = _crop_origin(rng, slack_x, 2)
        # |delta| <= min(yjitter, slack_y // 2) keeps the right crop rows y0+delta .. y0+delta+crop_h-1 inside
        jitter = min(self.yjitter, slack_y // 2)
        delta = int(rng.integers(-jitter, jitter, endpoint=True))
        return (s_y, s_x), size, (y0, x0), delta

    # ----------------------------------------------------------------------------------- apply

    def apply(self, sample: dict, params: AugmentParams) -> dict:
        """Apply drawn ``params`` to ``sample`` (the deterministic half of ``__call__``).

        Parameters
        ----------
        sample : dict
            ``left``, ``right``, ``disparity``, ``valid`` and any other keys (passed through).
        params : AugmentParams
            From :meth:`draw` for this sample's (H, W).

        Returns
        -------
        dict
            A new dict; the input arrays are not modified.

        Shapes
        ------
        See the class docstring.
        """
        self._check_sample(sample)
        left, right = np.asarray(sample["left"]), np.asarray(sample["right"])
        height, width = left.shape[:2]
        # cv2.resize(fx=s_x, fy=s_y) output size: rint(H * s_y), rint(W * s_x)
        expected = (int(np.rint(height * params.scale[0])), int(np.rint(width * params.scale[1])))
        (y0, x0), (ch, cw) = params.origin, self.crop
        # the left crop reads resized rows y0 .. y0+ch-1, the right one rows y0+delta .. y0+delta+ch-1
        if expected != tuple(params.size) or not (0 <= y0 and 0 <= y0 + params.delta and 0 <= x0
                                                  and max(y0, y0 + params.delta) + ch <= expected[0]
                                                  and x0 + cw <= expected[1]):
            raise ShapeError(f"{type(self).__name__}.apply: params do not fit a {height}x{width} image (scale "
                             f"{params.scale} gives {expected}, params say size {params.size}, crop {self.crop} "
                             f"at {params.origin} with delta {params.delta})")
        rows = _resize_taps(height, params.scale[0], y0, ch)
        rows_right = _resize_taps(height, params.scale[0], y0 + params.delta, ch)
        cols = _resize_taps(width, params.scale[1], x0, cw)
        (ly, ly_end), (ry, ry_end), (wx, wx_end) = _span(rows), _span(rows_right), _span(cols)
        left_window, right_window = self._color_and_occlude(
            left[ly:ly_end, wx:wx_end], right[ry:ry_end, wx:wx_end], (ry, wx), right, params)
        if params.veil is not None:
            left_window, right_window = params.veil.apply(left_window, ly), params.veil.apply(right_window, ry)
        disparity = np.asarray(sample["disparity"], dtype=np.float32)
        valid = np.asarray(sample["valid"], dtype=bool)
        finite = np.isfinite(disparity)
        if not finite.all():
            valid = valid & finite
            disparity = np.where(finite, disparity, np.float32(0))
        out = dict(sample)
        out["left"] = _resample(left_window, _shift_taps(rows, ly), _shift_taps(cols, wx))
        out["right"] = _resample(right_window, _shift_taps(rows_right, ry), _shift_taps(cols, wx))
        out["disparity"], out["valid"] = self._resize_ground_truth(disparity, valid, rows, cols, params)
        if self.max_disparity is not None:
            out["valid"] &= np.abs(out["disparity"]) < self.max_disparity
        if params.noise is not None:
            out["left"], out["right"] = params.noise.apply(out["left"], 0), params.noise.apply(out["right"], 1)
        return out

    @staticmethod
    def _color_and_occlude(left: np.ndarray, right: np.ndarray, right_origin: tuple[int, int],
                           right_full: np.ndarray, params: AugmentParams):
        """Steps 1-2 on the source windows the crop reads (``left``, ``right``: views of the inputs;
        ``right_origin``: (row, col) of ``right`` in ``right_full``).

        Shapes
        ------
        left: (h_l, w, 3), right: (h_r, w, 3) -> the same shapes, new arrays where changed.
        """
        color, right_color, pivot = params.color, None, None
        if len(color) == 2:
            left, _ = _apply_color(left, color[0])
            right, pivot = _apply_color(right, color[1])
            right_color = color[1]
        elif color:
            stacked, pivot = _apply_color(np.concatenate([left, right], axis=0), color[0])
            # split the vertically stacked pair back at the left window's height
            left, right = stacked[:left.shape[0]], stacked[left.shape[0]:]
            right_color = color[0]
        if not params.erase and params.patch is None:
            return left, right
        if not color:
            # still a view of the caller's image
            right = right.copy()
        fill = np.rint(right.reshape(-1, 3).mean(axis=0)).astype(np.uint8) if params.erase else None
        _erase(right, right_origin, params.erase, fill)
        if params.patch is not None:
            sy, sx, dy, dx, h, w = params.patch
            oy, ox = right_origin
            # the destination rectangle clipped to the window, in image coordinates
            top, bottom = max(dy, oy), min(dy + h, oy + right.shape[0])
            first, last = max(dx, ox), min(dx + w, ox + right.shape[1])
            if top < bottom and first < last:
                # the source pixels that land there: destination minus (dy - sy, dx - sx)
                src_top, src_first = top - dy + sy, first - dx + sx
                source = right_full[src_top:src_top + bottom - top, src_first:src_first + last - first]
                if right_color is not None:
                    source, _ = _apply_color(source, right_color, pivot)
                else:
                    source = source.copy()
                _erase(source, (src_top, src_first), params.erase, fill)
                right[top - oy:bottom - oy, first - ox:last - ox] = source
        return left, right

    def _resize_ground_truth(self, disparity: np.ndarray, valid: np.ndarray, rows, cols, params: AugmentParams):
        """Dense: bilinear disparity times s_x; a pixel is valid iff all its non-zero-weight sources are.

        Shapes
        ------
        disparity, valid: (H, W) -> (crop_h, crop_w).
        """
        disparity = _resample(disparity, rows, cols)
        if params.scale[1] != 1.0:
            disparity *= np.float32(params.scale[1])
        return disparity, _resample(valid, rows, cols)



class SparseStereoAugmentor(StereoAugmentor):
    """Augmentation for sparse ground truth (KITTI, ETH3D, Middlebury): RAFT-Stereo's
    ``SparseFlowAugmentor`` (architecture.md §3.3).

    Differences from :class:`StereoAugmentor`: one scale for both axes (no stretch), clamped to
    >= max((crop_h + 1) / H, (crop_w + 1) / W), applied with probability ``spatial_prob`` = 0.8;
    the disparity is resized by scattering every valid ground-truth pixel to its nearest resized
    pixel (value times s), never by interpolating between measured and missing values; crop origin
    y0 ~ U{0, H' - crop_h + 19}, x0 ~ U{-50, W' - crop_w + 49}, both then clipped into the image
    (RAFT's margins, which favour the bottom rows where KITTI has ground truth); no y-jitter;
    ColorJitter brightness and contrast 0.3, hue 0.3 / 3.14, always one draw for the stacked pair;
    validity is the reader's mask only (``max_disparity`` None).

    Parameters
    ----------
    crop : (int, int)
        Output size (crop_h, crop_w).
    brightness, contrast, hue, asymmetric_prob, spatial_prob, max_disparity
        As :class:`StereoAugmentor`, with the sparse defaults above.
    crop_margin : (int, int)
        (y, x) margins of the crop-origin draw, default (20, 50).
    **options
        Any other :class:`StereoAugmentor` option (photometric, saturation, gamma, gain,
        eraser_prob, eraser_size, patch_prob, spatial, scale_range).

    Shapes
    ------
    As :class:`StereoAugmentor`; at invalid output pixels the disparity is 0.
    """

    _clamp_margin = 1

    def __init__(self, crop: tuple[int, int], *, brightness=0.3, contrast=0.3, hue=0.3 / 3.14,
                 asymmetric_prob: float = 0.0, spatial_prob: float = 0.8, crop_margin: tuple[int, int] = (20, 50),
                 max_disparity: float | None = None, **options):
        for name in ("stretch_prob", "max_stretch", "yjitter"):
            if name in options:
                raise ArgumentError(f"SparseStereoAugmentor: {name} is not an option of the sparse augmentation")
        super().__init__(crop, brightness=brightness, contrast=contrast, hue=hue, asymmetric_prob=asymmetric_prob,
                         spatial_prob=spatial_prob, stretch_prob=0.0, yjitter=0, max_disparity=max_disparity, **options)
        self.crop_margin = _check_pair(crop_margin, "crop_margin", "SparseStereoAugmentor")
        if min(self.crop_margin) < 0:
            raise ArgumentError(f"SparseStereoAugmentor: crop_margin must be >= 0, got {crop_margin}")

    def _draw_geometry(self, height: int, width: int, rng: np.random.Generator):
        s_y, s_x = self._draw_scale(height, width, rng)
        # cv2.resize(fx=s_x, fy=s_y) output size: rint(W * s_x), rint(H * s_y)
        size = (int(np.rint(height * s_y)), int(np.rint(width * s_x)))
        slack_y, slack_x = size[0] - self.crop[0], size[1] - self.crop[1]
        margin_y, margin_x = self.crop_margin
        y0 = _margin_origin(rng, slack_y, 0, margin_y)
        x0 = _margin_origin(rng, slack_x, margin_x, margin_x)
        return (s_y, s_x), size, (y0, x0), 0

    def _resize_ground_truth(self, disparity: np.ndarray, valid: np.ndarray, rows, cols, params: AugmentParams):
        """Nearest scatter of the valid pixels: value times s_x, never interpolated with missing ones.

        Shapes
        ------
        disparity, valid: (H, W) -> (crop_h, crop_w).
        """
        (s_y, s_x), (y0, x0), (ch, cw) = params.scale, params.origin, self.crop
        # sources landing in resized rows y0 .. y0+ch-1 satisfy y + 0.5 in [y0 / s, (y0 + ch) / s]; one px of slack
        y_lo, y_hi = max(0, math.floor(y0 / s_y - 0.5) - 1), math.ceil((y0 + ch) / s_y - 0.5) + 2
        x_lo, x_hi = max(0, math.floor(x0 / s_x - 0.5) - 1), math.ceil((x0 + cw) / s_x - 0.5) + 2
        ys, xs = np.nonzero(valid[y_lo:y_hi, x_lo:x_hi])
        ys, xs = ys + y_lo, xs + x_lo
        # a source centre x lands at (x + 0.5) * s - 0.5 in the resized image; nearest pixel, minus the crop origin
        ty = np.rint((ys + 0.5) * s_y - 0.5).astype(np.intp) - y0
        tx = np.rint((xs + 0.5) * s_x - 0.5).astype(np.intp) - x0
        inside = (ty >= 0) & (ty < ch) & (tx >= 0) & (tx < cw)
        out_disparity = np.zeros((ch, cw), dtype=np.float32)
        out_valid = np.zeros((ch, cw), dtype=bool)
        # several sources can land on one pixel when downscaling: the last in row-major order wins
        out_disparity[ty[inside], tx[inside]] = disparity[ys[inside], xs[inside]] * np.float32(s_x)
        out_valid[ty[inside], tx[inside]] = True
        return out_disparity, out_valid

    def apply(self, sample: dict, params: AugmentParams) -> dict:
        """As :meth:`StereoAugmentor.apply`; the disparity is 0 at invalid output pixels.

        Shapes
        ------
        See :class:`StereoAugmentor`.
        """
        out = super().apply(sample, params)
        out["disparity"][~out["valid"]] = 0.0
        return out


def make_augmentor(crop: tuple[int, int], sparse: bool = False, augment: bool = True, **overrides) -> StereoAugmentor:
    """The architecture.md §3.3 augmentor for ``crop``: :class:`SparseStereoAugmentor` for sparse ground truth,
    else :class:`StereoAugmentor`.

    Parameters
    ----------
    crop : (int, int)
        Output size (crop_h, crop_w).
    sparse : bool
        KITTI / ETH3D / Middlebury-like sparse ground truth.
    augment : bool
        False: only the random crop (no colour, occluders, resize except the upscale of images
        smaller than the crop, y-jitter), for validation or gentle fine-tuning.
    **overrides
        Constructor options of the chosen class.

    Returns
    -------
    StereoAugmentor

    Shapes
    ------
    The augmentor maps (H, W) samples to (crop_h, crop_w) ones.
    """
    if not augment:
        off = dict(photometric=False, eraser_prob=0.0, patch_prob=0.0, spatial=False)
        if not sparse:
            off["yjitter"] = 0
        overrides = {**off, **overrides}
    cls = SparseStereoAugmentor if sparse else StereoAugmentor
    return cls(crop, **overrides)
