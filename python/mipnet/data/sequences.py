"""Generated stereo video with exact ground truth: a procedural scene filmed by a rig that sways along its baseline.

Geometry. :mod:`mipnet.data.scenes` describes every surface by a disparity field ``d(x, y)`` and a shape in the
coordinates of a reference left camera. A pinhole rig translated by ``s`` baselines along its baseline (the x axis,
parallel to the image plane) sees a point of disparity ``d`` at ``x' = x - s d`` in its left camera and at
``x' - d`` in its right camera, on the same row and at the same disparity: a sideways translation changes no
depth. So the left view of the rig at offset ``s`` is the scenes generator's right view of the scene with every
disparity field scaled by ``s``, and its right view that of the fields scaled by ``s + 1``: the generator's exact
closed-form renderer draws every frame (z-buffer, shading, visibility), and the disparity stays exact at every left
pixel centre. This is the sway of an ROV flying a survey transect; the rows, the depths and the lighting stay put,
and a near point moves ``s d`` pixels while the far background barely moves (parallax).

Motion. The offset eases from ``s_a`` to ``s_b`` (both in ``[0, MAX_OFFSET]``, ``|s_b - s_a|`` drawn in
``TRAVEL``), ``s(t) = s_a + (s_b - s_a) (1 - cos(pi t / (N - 1))) / 2``: zero speed at both ends, the fastest in the
middle (``pi / 2`` times the mean speed), smooth throughout. ``MAX_OFFSET`` keeps every frame inside the region the
scene generator fills (it covers the left-image x up to ``W + d_max``; the ground reaches about ``0.7 d_max``).

Correspondences. Frame t's pixel ``x`` shows the point seen at ``x + (s_t - s_{t-1}) d`` in frame t - 1 (same row).
``previous_x`` holds that position where the point is visible in both frames (inside frame t - 1's image and not
hidden there by a nearer surface), NaN elsewhere and on the first frame of each scene: temporal flicker is measured
through it (:mod:`mipnet.stereo.temporal`).

Appearance. One camera per view for the whole sequence (exposure, white balance, vignetting, blur: the scene
generator's camera, drawn once) with new sensor noise every frame. Under water (``water``), every frame is degraded
with the same water (:func:`mipnet.underwater.degrade`), marine snow and sensor noise drawn anew per frame.

A cut (``cut_at``): from that frame on, a second scene (its own seed and path) replaces the first, so that a stream's
reset is measured.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..errors import ArgumentError
from ..underwater.formation import degrade
from .scenes import _compose, _front, _shade, _Surface, apply_camera
from .synthetic import EVAL_SEED_START, _check_water, check_seed, check_size, water_for_item
from .datasets import Dataset

__all__ = ["make_sequence", "SequenceSet", "camera_path", "MAX_OFFSET", "TRAVEL", "DEFAULT_FRAMES"]

#: Largest rig offset in baselines: the views at s and s + 1 stay inside the region the scene generator fills.
MAX_OFFSET = 0.4
#: Range of the distance the rig travels over one scene, in baselines.
TRAVEL = (0.15, 0.4)
DEFAULT_FRAMES = 16
_TOLERANCE = 1e-6  # relative z-buffer tolerance of "the same point", as scenes' visibility test


def camera_path(rng: np.random.Generator, frames: int) -> np.ndarray:
    """The rig's offset in baselines at each of ``frames`` frames: an ease from ``s_a`` to ``s_b`` (module docstring).

    Shapes
    ------
    return: (frames,) float64, in [0, MAX_OFFSET].
    """
    travel = rng.uniform(*TRAVEL)
    start = rng.uniform(0.0, MAX_OFFSET - travel)
    forward = rng.random() < 0.5  # which way the rig moves
    s_a, s_b = (start, start + travel) if forward else (start + travel, start)
    t = np.arange(frames, dtype=np.float64) / max(frames - 1, 1)
    # ease: (1 - cos(pi t)) / 2 goes from 0 to 1 with zero slope at both ends
    return s_a + (s_b - s_a) * (1.0 - np.cos(np.pi * t)) / 2.0


def _scaled(surfaces: tuple, factor: float) -> tuple:
    """The surfaces with every disparity field (and disparity range) multiplied by ``factor`` > 0."""
    out = []
    for surface in surfaces:
        f = surface.field
        field = dataclasses.replace(f, c=f.c * factor, a=f.a * factor, b=f.b * factor, qxx=f.qxx * factor,
                                    qxy=f.qxy * factor, qyy=f.qyy * factor)
        out.append(_Surface(field=field, shape=surface.shape, paint=surface.paint, kind=surface.kind, box=surface.box,
                            d_range=(surface.d_range[0] * factor, surface.d_range[1] * factor)))
    return tuple(out)


class _Rig:
    """The views of one scene from the camera at offset ``s`` (in baselines along the baseline)."""

    def __init__(self, scene):
        self.scene = scene
        self._cache: dict[float, tuple] = {}

    def surfaces(self, offset: float) -> tuple[tuple, str]:
        """Surfaces and view name whose scenes-renderer view is the camera at ``offset``: the reference left view at
        0, else the right view of the fields scaled by ``offset`` (x' = x - offset d)."""
        if offset == 0.0:
            return self.scene.surfaces, "left"
        if offset not in self._cache:
            self._cache[offset] = _scaled(self.scene.surfaces, offset)
        return self._cache[offset], "right"

    def view(self, offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(owner, disparity, reference-left x) per pixel of the camera at ``offset`` (owner -1: nothing)."""
        height, width = self.scene.height, self.scene.width
        surfaces, name = self.surfaces(offset)
        owner, best, x_left = _front(surfaces, name, height, width)
        # the z-buffer of the scaled fields holds offset * d
        return owner, best / offset if offset else best, x_left

    def front(self, offset: float, x_query: np.ndarray) -> np.ndarray:
        """The disparity of the nearest surface at view-x ``x_query`` (one per pixel, on the pixel's row) of the
        camera at ``offset``; -inf where none.

        Shapes
        ------
        x_query: (H, W) -> (H, W) float64.
        """
        height, width = self.scene.height, self.scene.width
        surfaces, name = self.surfaces(offset)
        columns = np.arange(width, dtype=np.float64)
        reach = columns - x_query  # column - x_query: what _front needs to bound its search
        _, best, _ = _front(surfaces, name, height, width, x_query=x_query,
                            shift=(float(reach.min()), float(reach.max())))
        return best / offset if offset else best

    def seen(self, offset: float, x_query: np.ndarray, disparity: np.ndarray) -> np.ndarray:
        """Whether the point of ``disparity`` at view-x ``x_query`` is inside the image of the camera at ``offset``
        and not hidden there by a nearer surface.

        Shapes
        ------
        x_query, disparity: (H, W) -> bool (H, W).
        """
        width = self.scene.width
        inside = (x_query >= 0) & (x_query <= width - 1)
        return inside & (self.front(offset, x_query) <= disparity + _TOLERANCE * max(1.0, width))


def _render_frame(rig: _Rig, offset: float, cameras: tuple, noise: tuple) -> dict:
    """One frame of the rig at ``offset``: the left camera at ``offset``, the right one at ``offset + 1``."""
    scene = rig.scene
    owner_left, disparity, x_left = rig.view(offset)
    owner_right, _, x_left_right = rig.view(offset + 1.0)
    x = np.arange(scene.width, dtype=np.float64)
    valid = rig.seen(offset + 1.0, x - disparity, disparity)
    # one camera each for the whole sequence (a copy of its generator in the same state), new noise each frame
    left = apply_camera(copy.deepcopy(cameras[0]), _shade(scene, owner_left, x_left), noise_rng=noise[0])
    right = apply_camera(copy.deepcopy(cameras[1]), _shade(scene, owner_right, x_left_right), noise_rng=noise[1])
    return {"left": left, "right": right, "disparity": disparity.astype(np.float32), "valid": valid}


def _scene_seed(seed: int, scene: int) -> int:
    """The scenes-generator seed of scene ``scene`` (0, or 1 after a cut) of sequence ``seed``."""
    if scene == 0:
        return seed
    return int(np.random.SeedSequence([seed, scene]).generate_state(1)[0])


def make_sequence(seed: int, frames: int = DEFAULT_FRAMES, size: tuple[int, int] = (384, 512), water=None,
                  cut_at: int | None = None) -> list[dict]:
    """A generated stereo video with exact disparity and frame-to-frame correspondences (see the module docstring).

    Parameters
    ----------
    seed : int
        Non-negative sequence seed; the sequence is a deterministic function of all the arguments (and, for the
        colours only, of the photographs installed, as :func:`mipnet.data.make_scene`). Frame 0 shows the scene of
        ``make_scene(H, W, seed)`` from the rig's first offset.
    frames : int
        Number of frames, at least 1.
    size : (int, int)
        (H, W) of every frame.
    water : None, str, WaterParams or dict
        None: in air; else the water of every frame, as ``underwater`` of :class:`mipnet.data.SceneStereo`
        (a preset name of :data:`mipnet.underwater.PRESETS`, ``"random"``: drawn once for the sequence, a
        ``WaterParams`` or a dict of :func:`mipnet.underwater.degrade` keywords).
    cut_at : int, optional
        From this frame on (1 <= cut_at < frames) a different scene with its own path.

    Returns
    -------
    list of dict
        One dict a frame: ``left``, ``right`` (uint8 RGB), ``disparity`` (float32, exact), ``valid`` (bool: seen in
        the right view), ``previous_x`` (float32: the x in the previous frame of this pixel's point where it is
        visible in both, NaN elsewhere and on each scene's first frame), ``offset`` (the rig's offset in baselines),
        ``scene`` (0, or 1 from the cut on) and ``meta``.

    Shapes
    ------
    left, right: (H, W, 3); disparity, valid, previous_x: (H, W).
    """
    seed = check_seed("make_sequence", seed)
    if not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or frames < 1:
        raise ArgumentError(f"make_sequence: frames must be a positive integer, got {frames!r}")
    try:
        height, width = size
    except (TypeError, ValueError):
        raise ArgumentError(f"make_sequence: size must be (H, W), got {size!r}") from None
    height, width = check_size("make_sequence", height, width)
    if cut_at is not None and not (isinstance(cut_at, (int, np.integer)) and not isinstance(cut_at, bool)
                                   and 1 <= cut_at < frames):
        raise ArgumentError(f"make_sequence: cut_at must be a frame index in [1, {frames - 1}] or None, got {cut_at!r}")
    _check_water("make_sequence", water)
    options, label = water_for_item(water, seed)
    starts = [0] if cut_at is None else [0, int(cut_at)]
    ends = starts[1:] + [int(frames)]
    sequence = []
    for scene_index, (start, end) in enumerate(zip(starts, ends)):
        scene_seed = _scene_seed(seed, scene_index)
        scene, cameras = _compose(scene_seed, height, width, width / 4.0)
        rig = _Rig(scene)
        path = camera_path(np.random.default_rng([seed, scene_index, 0]), end - start)
        previous = None
        for step, offset in enumerate(path):
            t = start + step
            noise = tuple(np.random.default_rng([seed, scene_index, 1, t, view]) for view in (0, 1))
            frame = _render_frame(rig, float(offset), cameras, noise)
            if previous is None:
                frame["previous_x"] = np.full((height, width), np.nan, dtype=np.float32)
            else:
                # the point at x is at x + (s_t - s_{t-1}) d in the previous frame (same row, same disparity)
                x_previous = np.arange(width, dtype=np.float64) + (offset - previous) * frame["disparity"]
                covisible = rig.seen(previous, x_previous, frame["disparity"].astype(np.float64))
                frame["previous_x"] = np.where(covisible, x_previous, np.nan).astype(np.float32)
            if options is not None:
                water_seed = int(np.random.SeedSequence([seed, 3, t]).generate_state(1)[0])
                frame["left"], frame["right"] = degrade(frame["left"], frame["right"], frame["disparity"],
                                                        seed=water_seed, **options)
            frame["offset"], frame["scene"] = float(offset), scene_index
            frame["meta"] = {"dataset": "sequence", "seed": seed, "frame": t, "scene_seed": scene_seed,
                             "underwater": label}
            sequence.append(frame)
            previous = float(offset)
    return sequence


class SequenceSet(Dataset):
    """``n`` generated sequences of :func:`make_sequence`; item i is the sequence of seed ``seed + i``.

    Items are dicts ``{"frames": [frame dicts of make_sequence], "meta": {...}}``. Evaluation sequences
    (``mipnet eval --dataset sequence``) start at :data:`EVAL_SEED_START`, as the other generated sets.

    Shapes
    ------
    frames: see :func:`make_sequence`.
    """

    name = "sequence"

    def __init__(self, n: int, height: int, width: int, seed: int = EVAL_SEED_START, frames: int = DEFAULT_FRAMES,
                 water=None, cut_at: int | None = None):
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 0:
            raise ArgumentError(f"SequenceSet: n must be a non-negative integer, got {n!r}")
        self.n = int(n)
        self.height, self.width = check_size("SequenceSet", height, width)
        self.seed = check_seed("SequenceSet", seed)
        if not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or frames < 1:
            raise ArgumentError(f"SequenceSet: frames must be a positive integer, got {frames!r}")
        if cut_at is not None and not 1 <= cut_at < frames:
            raise ArgumentError(f"SequenceSet: cut_at must be in [1, {frames - 1}] or None, got {cut_at!r}")
        _check_water("SequenceSet", water)
        self.frames, self.water, self.cut_at = int(frames), water, cut_at

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int) -> dict:
        index = self._check_index(index)
        seed = self.seed + index
        frames = make_sequence(seed, frames=self.frames, size=(self.height, self.width), water=self.water,
                               cut_at=self.cut_at)
        return {"frames": frames, "meta": {"dataset": self.name, "index": index, "seed": seed,
                                           "underwater": frames[0]["meta"]["underwater"], "cut_at": self.cut_at}}
