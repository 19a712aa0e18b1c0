"""Procedural stereo pairs with exact disparity, for tests, demos and synthetic-underwater evaluation.

A scene is a stack of textured planar surfaces: a slanted background plane covering everything
plus a few slanted discs, ellipses and rectangles in front of it. Each surface has a disparity
plane ``d(x, y) = a*x + b*y + c`` in left-image coordinates, and its texture is a function of
the left-image coordinates of the surface point, so both views sample the same texture at the
same 3-D point. A right-view pixel ``(xr, y)`` sees the point of surface s whose left position
``x`` satisfies ``x - d(x, y) = xr``, i.e. ``x = (xr + b*y + c) / (1 - a)``. Visibility in each
view is a z-buffer on disparity (larger = nearer).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError
from .datasets import Dataset

EVAL_SEED_START = 1_000_000  # training pairs use seeds below it, evaluation pairs from it on
# training-time validation (checkpoint choice) draws from here, away from the evaluation pairs of
# `mipnet eval` (seeds 1,000,000 on), so no choice is made on a pair that measures the result
VALIDATION_SEED_START = 2_000_000

__all__ = ["make_pair", "GeneratedStereo", "SyntheticStereo", "synthetic_underwater_pairs", "EVAL_SEED_START",
           "VALIDATION_SEED_START"]

_TABLE_SIZE = 256  # value-noise lattice period (power of two: wrap with a bit mask)
_OCTAVES = ((40.0, 0.45), (14.0, 0.35), (6.0, 0.20))  # (period px, amplitude) of luminance noise
_CHROMA_PERIOD = 60.0


@dataclass(frozen=True)
class _Surface:
    a: float  # disparity plane d = a*x + b*y + c (left-image coordinates)
    b: float
    c: float
    kind: str  # "plane" (unbounded), "ellipse" or "rectangle"
    centre: tuple[float, float]
    half_axes: tuple[float, float]
    angle: float
    color: tuple[float, float, float]
    texture_angle: float
    texture_offset: tuple[float, float]
    stripe_period: float  # 0: no stripes

    def disparity(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return self.a * x + self.b * y + self.c

    def left_x(self, x_view: np.ndarray, y: np.ndarray, view: str) -> np.ndarray:
        """Left-image x of the surface point seen at ``x_view`` in ``view``."""
        if view == "left":
            return x_view
        return (x_view + self.b * y + self.c) / (1.0 - self.a)

    def covers(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        if self.kind == "plane":
            return np.ones(np.shape(x), dtype=bool)
        u, v = _rotate(x - self.centre[0], y - self.centre[1], self.angle)
        hu, hv = self.half_axes
        if self.kind == "ellipse":
            return (u / hu) ** 2 + (v / hv) ** 2 <= 1.0
        return (np.abs(u) <= hu) & (np.abs(v) <= hv)


def _rotate(x, y, angle: float):
    cos, sin = np.cos(angle), np.sin(angle)
    return cos * x + sin * y, -sin * x + cos * y


def _value_noise(table: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Smooth lattice noise in [0, 1]: smoothstep interpolation of a periodic random table."""
    mask = _TABLE_SIZE - 1
    iu, iv = np.floor(u), np.floor(v)
    fu, fv = u - iu, v - iv
    su, sv = fu * fu * (3 - 2 * fu), fv * fv * (3 - 2 * fv)
    i0, j0 = iu.astype(np.int64) & mask, iv.astype(np.int64) & mask
    i1, j1 = (i0 + 1) & mask, (j0 + 1) & mask
    top = table[j0, i0] + su * (table[j0, i1] - table[j0, i0])
    bottom = table[j1, i0] + su * (table[j1, i1] - table[j1, i0])
    return top + sv * (bottom - top)


def _texture(surface: _Surface, table: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] of the surface at left-image coordinates (x, y)."""
    u, v = _rotate(x, y, surface.texture_angle)
    u = u + surface.texture_offset[0]
    v = v + surface.texture_offset[1]
    luminance = sum(amp * _value_noise(table, u / period, v / period) for period, amp in _OCTAVES)
    if surface.stripe_period > 0:
        luminance = 0.6 * luminance + 0.4 * (0.5 + 0.5 * np.sin(2 * np.pi * u / surface.stripe_period))
    # Per-channel low-frequency colour variation, read from shifted parts of the same table.
    chroma = np.stack(
        [_value_noise(table, (u + 97.0 * k) / _CHROMA_PERIOD, (v + 61.0 * k) / _CHROMA_PERIOD) for k in range(3)],
        axis=-1,
    )
    rgb = np.asarray(surface.color) * (0.25 + 0.75 * luminance[..., None]) + 0.25 * (chroma - 0.5)
    return np.clip(rgb, 0.0, 1.0)


def _plane_through(rng: np.random.Generator, centre, d_centre: float, extent: float, max_relative: float):
    """Disparity-plane coefficients (a, b, c) with value ``d_centre`` at ``centre`` and a slant that
    changes the disparity by at most ``max_relative * d_centre`` within ``extent`` pixels of it.

    |a| <= 0.3 keeps ``1 - a`` (the right-view stretch) well away from 0.
    """
    magnitude = rng.uniform(0.0, max_relative * d_centre / max(extent, 1.0))
    direction = rng.uniform(0.0, 2 * np.pi)
    gx = float(np.clip(magnitude * np.cos(direction), -0.3, 0.3))
    gy = float(np.clip(magnitude * np.sin(direction), -0.3, 0.3))
    return gx, gy, d_centre - gx * centre[0] - gy * centre[1]


def _random_surface(rng: np.random.Generator, kind: str, plane, centre, half_axes, angle) -> _Surface:
    return _Surface(
        *plane, kind=kind, centre=centre, half_axes=half_axes, angle=angle,
        color=tuple(rng.uniform(0.2, 1.0, 3)),
        texture_angle=float(rng.uniform(0, np.pi)),
        texture_offset=tuple(rng.uniform(0, _TABLE_SIZE * _OCTAVES[-1][0], 2)),
        stripe_period=float(rng.uniform(5.0, 12.0)) if rng.random() < 0.25 else 0.0,
    )


def _scene(rng: np.random.Generator, height: int, width: int) -> list[_Surface]:
    """Background plane first, then 4-8 objects; all disparities within (0, 1.25 * max(4, width / 8)]."""
    d_max = max(4.0, width / 8.0)
    size = min(height, width)
    centre = ((width - 1) / 2, (height - 1) / 2)
    background_plane = _plane_through(rng, centre, rng.uniform(0.08, 0.25) * d_max, np.hypot(width, height) / 2, 0.35)
    surfaces = [_random_surface(rng, "plane", background_plane, centre, (np.inf, np.inf), 0.0)]
    for _ in range(int(rng.integers(4, 9))):
        kind = "ellipse" if rng.random() < 0.5 else "rectangle"
        half_axes = tuple(float(h) for h in np.maximum(rng.uniform(0.06, 0.25, 2) * size, 2.0))
        if kind == "ellipse" and rng.random() < 0.4:
            half_axes = (half_axes[0], half_axes[0])  # a disc
        object_centre = (float(rng.uniform(-0.1, 1.1) * width), float(rng.uniform(-0.1, 1.1) * height))
        plane = _plane_through(rng, object_centre, rng.uniform(0.3, 1.0) * d_max, np.hypot(*half_axes), 0.25)
        surfaces.append(_random_surface(rng, kind, plane, object_centre, half_axes, float(rng.uniform(0, np.pi))))
    return surfaces


def _visible(surfaces: list[_Surface], x: np.ndarray, y: np.ndarray, view: str):
    """Front-most surface index and its disparity at view coordinates (x, y)."""
    best = np.full(x.shape, -np.inf)
    owner = np.full(x.shape, -1, dtype=np.int64)
    for index, surface in enumerate(surfaces):
        x_left = surface.left_x(x, y, view)
        disparity = surface.disparity(x_left, y)
        nearer = surface.covers(x_left, y) & (disparity > best)
        best[nearer] = disparity[nearer]
        owner[nearer] = index
    return owner, best


def _render(surfaces: list[_Surface], table: np.ndarray, x: np.ndarray, y: np.ndarray, view: str) -> np.ndarray:
    owner, _ = _visible(surfaces, x, y, view)
    image = np.zeros(x.shape + (3,))
    for index, surface in enumerate(surfaces):
        here = owner == index
        if here.any():
            image[here] = _texture(surface, table, surface.left_x(x[here], y[here], view), y[here])
    return np.rint(image * 255).astype(np.uint8)


def make_pair(height: int, width: int, seed: int = 0) -> dict:
    """A procedural rectified stereo pair with exact left disparity.

    Parameters
    ----------
    height, width : int
        Image size (any positive size).
    seed : int
        Scene seed; the pair is a deterministic function of (height, width, seed).

    Returns
    -------
    dict
        ``left``, ``right``: uint8 RGB; ``disparity``: float32, exact at every left pixel centre
        (positive, at most 1.25 * max(4, width / 8)); ``valid``: bool, False where the left pixel is
        occluded in the right view or projects outside it.

    Shapes
    ------
    left, right: (H, W, 3); disparity, valid: (H, W).
    """
    if height < 1 or width < 1:
        raise ValueError(f"make_pair: size must be positive, got {height}x{width}")
    rng = np.random.default_rng(seed)
    table = rng.random((_TABLE_SIZE, _TABLE_SIZE))
    surfaces = _scene(rng, height, width)
    y, x = np.indices((height, width), dtype=np.float64)
    owner, disparity = _visible(surfaces, x, y, "left")
    x_right = x - disparity
    # Seen in the right view iff no surface at the right-view point is nearer than this one
    # (the surface itself gives the same disparity there, up to rounding).
    _, front = _visible(surfaces, x_right, y, "right")
    valid = (x_right >= 0) & (x_right <= width - 1) & (front <= disparity + 1e-6 * max(1.0, width))
    return {
        "left": _render(surfaces, table, x, y, "left"),
        "right": _render(surfaces, table, x, y, "right"),
        "disparity": disparity.astype(np.float32),
        "valid": valid,
    }


def water_for_item(underwater, seed: int) -> tuple[dict | None, str | None]:
    """``degrade`` keyword arguments and a label for one pair: None (in air), a preset name, a
    ``WaterParams``, a dict of ``degrade`` arguments, or ``"random"`` (water drawn around the
    presets by :func:`mipnet.underwater.random_water` from a generator seeded by the pair seed)."""
    if underwater is None:
        return None, None
    if isinstance(underwater, str) and underwater == "random":
        from ..underwater.water import random_water

        return {"preset": random_water(np.random.default_rng([seed, 2]))}, "random"
    if isinstance(underwater, dict):
        options = dict(underwater)
        preset = options.get("preset", "coastal")
        return options, preset if isinstance(preset, str) else "custom"
    return {"preset": underwater}, underwater if isinstance(underwater, str) else "custom"


def apply_water(pair: dict, underwater, seed: int, survey: bool = False, texture_snr: bool = False) -> str | None:
    """Degrades ``pair``'s images in place as :func:`water_for_item` says; returns the label.

    ``survey``: the water's baseline and range clip are fitted to the pair first
    (:func:`mipnet.underwater.survey_water`: the scene inside the water's visibility). ``texture_snr``: also
    stores ``pair["texture_snr"]``, the texture SNR of the clean left view under that water
    (:func:`mipnet.underwater.texture_snr`, float32 (H, W)), computed before the images are degraded.
    """
    from ..underwater.formation import degrade
    from ..underwater.formation import texture_snr as texture_snr_map

    options, label = water_for_item(underwater, seed)
    if options is not None:
        if survey:
            from ..underwater.survey import survey_water
            from ..underwater.water import resolve_params

            overrides = dict(options)
            water = resolve_params(overrides.pop("preset", "coastal"), overrides)
            options = {"preset": survey_water(water, pair["disparity"])}
        if texture_snr:
            pair["texture_snr"] = texture_snr_map(pair["left"], pair["disparity"], **options)
        pair["left"], pair["right"] = degrade(pair["left"], pair["right"], pair["disparity"],
                                              seed=int(np.random.SeedSequence([seed, 1]).generate_state(1)[0]), **options)
    return label


def check_size(function: str, height, width) -> tuple[int, int]:
    if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 1 for v in (height, width)):
        raise ArgumentError(f"{function}: height and width must be positive integers, got {height!r} x {width!r}")
    return int(height), int(width)


def check_seed(function: str, seed) -> int:
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ArgumentError(f"{function}: seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def _check_water(owner: str, underwater) -> None:
    from ..underwater.water import PRESETS, WaterParams, resolve_params

    if isinstance(underwater, dict):
        options = dict(underwater)
        try:
            resolve_params(options.pop("preset", "coastal"), options)
        except (TypeError, ValueError) as error:
            raise ArgumentError(f"{owner}: bad underwater options {underwater!r}: {error}") from None
    elif not (underwater is None or underwater == "random" or isinstance(underwater, WaterParams)
              or (isinstance(underwater, str) and underwater in PRESETS)):
        raise ArgumentError(f"{owner}: underwater must be None, 'random', a WaterParams, a dict or one of "
                            f"{list(PRESETS)}, got {underwater!r}")


class GeneratedStereo(Dataset):
    """``n`` generated pairs; item i is ``generate(height, width, seed + i)``, optionally underwater.

    Training sets use pair seeds below :data:`EVAL_SEED_START` (1,000,000) and evaluation sets
    (``mipnet eval`` by default) start at it; a set may not straddle it.

    Parameters
    ----------
    n : int
        Number of pairs.
    height, width : int
        Image size.
    seed : int
        First pair seed.
    underwater : None, str, WaterParams or dict
        None: in air; a preset name of :data:`mipnet.underwater.PRESETS`; ``"random"``: water drawn
        per item by :func:`mipnet.underwater.random_water` from a generator seeded by the pair seed;
        a ``WaterParams``; or a dict of :func:`mipnet.underwater.degrade` keyword arguments
        (``preset`` plus ``WaterParams`` overrides).
    survey : bool
        Under water only: fit the water's baseline and range clip to each pair so that the scene lies within
        the water's visibility, as a survey flies (:func:`mipnet.underwater.survey_water`); the water is drawn
        as without it, and so are the scenes.
    texture_snr : bool
        Under water only: items also carry ``texture_snr``, the texture SNR of the clean left view under the
        item's water (:func:`mipnet.underwater.texture_snr`, window 9, sigma 3), for scoring by visibility;
        off by default (it costs about 60% of the time of the degradation itself).

    Shapes
    ------
    items: left, right (H, W, 3) uint8; disparity (H, W) float32; valid (H, W) bool; with ``texture_snr``, texture_snr
    (H, W) float32.
    """

    name = "generated"

    def __init__(self, n: int, height: int, width: int, seed: int = 0, underwater=None, survey: bool = False,
                 texture_snr: bool = False):
        owner = type(self).__name__
        if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 0:
            raise ArgumentError(f"{owner}: n must be a non-negative integer, got {n!r}")
        self.n = int(n)
        self.height, self.width = check_size(owner, height, width)
        self.seed = check_seed(owner, seed)
        if self.n and self.seed < EVAL_SEED_START <= self.seed + self.n - 1:
            raise ArgumentError(f"{owner}: seeds {self.seed}..{self.seed + self.n - 1} straddle {EVAL_SEED_START:,} "
                                "(training seeds lie below it, evaluation seeds from it on)")
        _check_water(owner, underwater)
        if underwater is None and (survey or texture_snr):
            raise ArgumentError(f"{owner}: survey and texture_snr need water (underwater=None: the pairs are in air)")
        self.underwater = underwater
        self.survey, self.texture_snr = bool(survey), bool(texture_snr)

    def generate(self, height: int, width: int, seed: int) -> dict:
        raise NotImplementedError

    def extra_meta(self) -> dict:
        return {}

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int) -> dict:
        index = self._check_index(index)
        seed = self.seed + index
        pair = self.generate(self.height, self.width, seed)
        label = apply_water(pair, self.underwater, seed, survey=self.survey, texture_snr=self.texture_snr)
        survey = {"survey": True} if self.survey else {}  # the keys of the other sets' items stay as they were
        pair["meta"] = {"dataset": self.name, "index": index, "seed": seed, "underwater": label, **survey,
                        **self.extra_meta(), **pair.get("meta", {})}
        return pair


class SyntheticStereo(GeneratedStereo):
    """``n`` planar procedural pairs of :func:`make_pair` (see :class:`GeneratedStereo`)."""

    name = "synthetic"

    def generate(self, height: int, width: int, seed: int) -> dict:
        return make_pair(height, width, seed)


def synthetic_underwater_pairs(
    n: int, height: int, width: int, preset: str = "turbid", seed: int = 0
) -> SyntheticStereo:
    """Evaluation pairs: procedural scenes degraded with an underwater preset.

    Returns a :class:`SyntheticStereo` (indexable and iterable), e.g. for
    :func:`mipnet.stereo.evaluation.evaluate_method`.

    Shapes
    ------
    items: left, right (H, W, 3) uint8; disparity (H, W) float32; valid (H, W) bool.
    """
    return SyntheticStereo(n, height, width, seed=seed, underwater=preset)
