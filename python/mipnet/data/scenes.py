"""Procedural stereo scenes that teach matching rather than the look of a generator.

A second generator beside :func:`mipnet.data.make_pair` (which stays as it is: tests and evaluations
depend on its seeds). A scene is a z-buffered stack of tens of textured surfaces:

* a far background and often a ground plane (disparity linear in y, as in driving scenes), a few
  large strongly slanted walls;
* tens of objects (ellipses, rotated rectangles, star-shaped blobs) at many depths, with planar,
  dome, cylinder or saddle disparity;
* thin structures: poles, (sagging) wires, branching trees, fences and grids with holes;
* disparity up to ``max_disparity`` (default a quarter of the width) with a long-tailed histogram:
  surface disparities are drawn log-uniformly (i.e. depth log-uniformly), so small and medium
  disparities dominate and large ones form a tail, and nearer objects are drawn larger.

Geometry. Every surface has a disparity field, quadratic in left-image coordinates,
``d(x, y) = c + a u + b v + qxx u^2 + qxy u v + qyy v^2`` with ``u = x - x0, v = y - y0``, and a
shape mask, both in left-image coordinates. Over its bounding box the slope ``dd/dx`` stays within
+-0.5, so ``x -> x - d(x, y)`` is increasing and a right-view pixel ``(xr, y)`` sees the surface
point whose left x solves ``x - d(x, y) = xr``, a quadratic in u solved in closed form. Each view
is a z-buffer on disparity (larger = nearer) over each surface's bounding box only. The disparity is
exact at left pixel centres; ``valid`` is False where the left pixel's point is hidden in the right
view (a nearer surface at ``(x - d, y)``, found by evaluating every surface there) or falls outside it.

Appearance. A surface's colour is a function of the left-image coordinates of its points, so both
views see the same texture at the same 3-D point: a texture (see :mod:`mipnet.data.textures`:
crops of real photographs where their packages are installed, dead leaves, 1/f noise, periodic
patterns) mapped with its own rotation, scale and offset, a colour transform (mean colour, contrast,
saturation, hue turn) and smooth shading. Some surfaces are deliberately textureless or low in
contrast. Then each view gets its own camera: exposure and white balance, vignetting, slight blur,
signal-dependent noise.

Reproducibility. A pair is a deterministic function of (height, width, seed, max_disparity). The
geometry (disparity, valid) does not depend on which photographs are installed; the colours do, so
:data:`GENERATOR_VERSION` names the photo sources found here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError
from ..random import log_uniform
from . import textures
from .synthetic import EVAL_SEED_START, GeneratedStereo, _rotate, check_seed, check_size

__all__ = ["make_scene", "SceneStereo", "GENERATOR_VERSION", "EVAL_SEED_START"]

_SOURCES = textures.photo_sources()
GENERATOR_VERSION = "scenes-1+" + ("photos:" + ",".join(_SOURCES) if _SOURCES else "procedural-only")

_MAX_X_SLOPE = 0.5  # |dd/dx| bound over a surface's box: x - d(x) stays increasing, stretch in [2/3, 2]
_D_FLOOR = 0.004  # smallest disparity, as a fraction of the maximum
_REFERENCE_AREA = 160 * 320  # object counts grow with sqrt(area / this)
_BLOB_ANGLES = 512  # star-shaped blob radius table resolution
_PHOTO_SHARE = 0.4  # share of surfaces textured with a photograph, where photographs exist
_PROCEDURAL_SHARE = {"pink": 0.35, "leaves": 0.4, "periodic": 0.25}
_CHROMA = textures.CHROMA_AXES
_OPPONENT = np.vstack([np.full(3, 1.0 / np.sqrt(3.0)), _CHROMA])  # orthonormal (grey, chroma, chroma)


# ---------------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class _Disparity:
    """``d(x, y) = c + a u + b v + qxx u^2 + qxy u v + qyy v^2``, ``u = x - x0``, ``v = y - y0``."""

    x0: float
    y0: float
    c: float
    a: float = 0.0
    b: float = 0.0
    qxx: float = 0.0
    qxy: float = 0.0
    qyy: float = 0.0

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u, v = x - self.x0, y - self.y0
        return self.c + u * (self.a + self.qxx * u + self.qxy * v) + v * (self.b + self.qyy * v)

    def left_x(self, x_right: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Left x of the point seen at ``x_right`` in the right view (NaN where there is none)."""
        v = y - self.y0
        # x - d(x, y) = x_right  <=>  qxx u^2 - slope u + rest = 0 with these two terms:
        slope = 1.0 - self.a - self.qxy * v
        rest = x_right - self.x0 + self.c + v * (self.b + self.qyy * v)
        if self.qxx == 0.0:
            return self.x0 + rest / slope  # linear in u: slope u = rest
        discriminant = slope * slope - 4.0 * self.qxx * rest
        # The root where d(x - d)/dx = sqrt(discriminant) > 0, written 2 rest / (slope + sqrt(disc))
        # (no cancellation, and it is rest / slope when qxx = 0).
        root = np.sqrt(np.maximum(discriminant, 0.0))
        return np.where(discriminant >= 0.0, self.x0 + 2.0 * rest / (slope + root), np.nan)

    def _reach(self, box) -> tuple[float, float]:
        """Largest |u| and |v| inside a left-image box (xmin, xmax, ymin, ymax)."""
        return max(abs(box[0] - self.x0), abs(box[1] - self.x0)), max(abs(box[2] - self.y0), abs(box[3] - self.y0))

    def spread(self, box) -> float:
        """Bound on |d - c| inside the box."""
        hu, hv = self._reach(box)
        return (abs(self.a) * hu + abs(self.b) * hv + abs(self.qxx) * hu * hu + abs(self.qxy) * hu * hv
                + abs(self.qyy) * hv * hv)

    def x_slope(self, box) -> float:
        """Bound on |dd/dx| = |a + 2 qxx u + qxy v| inside the box."""
        hu, hv = self._reach(box)
        return abs(self.a) + 2.0 * abs(self.qxx) * hu + abs(self.qxy) * hv


def _fit(field: _Disparity, box, d_floor: float, d_max: float, relative: float) -> _Disparity:
    """Shrink slant and curvature, then move c, until inside ``box``: |dd/dx| <= 0.5,
    |d - c| <= relative * c and <= 0.45 * (d_max - d_floor), and d_floor <= d <= d_max."""
    slope = field.x_slope(box)
    if slope > _MAX_X_SLOPE:
        shrink = _MAX_X_SLOPE / slope
        field = dataclasses.replace(field, a=field.a * shrink, qxx=field.qxx * shrink, qxy=field.qxy * shrink)
    spread = field.spread(box)
    cap = min(relative * field.c, 0.45 * (d_max - d_floor))
    if spread > cap:
        shrink = cap / spread
        field = dataclasses.replace(field, a=field.a * shrink, b=field.b * shrink, qxx=field.qxx * shrink,
                                    qxy=field.qxy * shrink, qyy=field.qyy * shrink)
        spread = cap
    return dataclasses.replace(field, c=float(np.clip(field.c, d_floor + spread, d_max - spread)))


def _rotated_box(centre, angle: float, along: tuple[float, float], across: tuple[float, float]):
    """Axis-aligned box of the rectangle {centre + t e + n e_perp}, t in ``along``, n in ``across``,
    e = (cos angle, sin angle)."""
    cos, sin = np.cos(angle), np.sin(angle)
    t = np.array([along[0], along[1], along[0], along[1]])
    n = np.array([across[0], across[0], across[1], across[1]])
    # Inverse of _rotate: x = cx + t cos - n sin, y = cy + t sin + n cos.
    x = centre[0] + t * cos - n * sin
    y = centre[1] + t * sin + n * cos
    return float(x.min()), float(x.max()), float(y.min()), float(y.max())


@dataclass(frozen=True)
class _Region:
    """Axis-aligned rectangle (backgrounds, ground)."""

    box: tuple

    def covers(self, x, y):
        return (x >= self.box[0]) & (x <= self.box[1]) & (y >= self.box[2]) & (y <= self.box[3])


@dataclass(frozen=True)
class _Oriented:
    """A shape given in its own frame: centre, half axes along and across, rotation angle."""

    centre: tuple
    half_axes: tuple
    angle: float

    @property
    def box(self):
        return _rotated_box(self.centre, self.angle, (-self.half_axes[0], self.half_axes[0]),
                            (-self.half_axes[1], self.half_axes[1]))

    def _local(self, x, y):
        """(u, v): the point in the shape's frame (rotated about the centre)."""
        return _rotate(x - self.centre[0], y - self.centre[1], self.angle)


class _Ellipse(_Oriented):
    def covers(self, x, y):
        u, v = self._local(x, y)
        return (u / self.half_axes[0]) ** 2 + (v / self.half_axes[1]) ** 2 <= 1.0


class _Rectangle(_Oriented):
    def covers(self, x, y):
        u, v = self._local(x, y)
        return (np.abs(u) <= self.half_axes[0]) & (np.abs(v) <= self.half_axes[1])


@dataclass(frozen=True)
class _Blob:
    """Star-shaped region: radius(theta) from a table over [0, 2 pi), stretched by ``aspect``."""

    centre: tuple
    radii: np.ndarray
    aspect: float
    angle: float

    @property
    def box(self):
        reach = float(self.radii.max())
        return _rotated_box(self.centre, self.angle, (-reach * self.aspect, reach * self.aspect), (-reach, reach))

    def covers(self, x, y):
        u, v = _rotate(x - self.centre[0], y - self.centre[1], self.angle)
        u = u / self.aspect
        # Table index of the polar angle of (u, v): theta / (2 pi) * entries, wrapped.
        index = np.rint(np.arctan2(v, u) * (_BLOB_ANGLES / (2 * np.pi))).astype(np.int64) % _BLOB_ANGLES
        return u * u + v * v <= self.radii[index] ** 2


@dataclass(frozen=True)
class _Band:
    """A thin curved stroke: from ``start`` along direction ``angle`` for ``length`` px, its centre
    line bent to n(t) = sag * t * (t - length), half width tapering from ``widths[0]`` to ``widths[1]``."""

    start: tuple
    angle: float
    length: float
    sag: float
    widths: tuple

    @property
    def box(self):
        bend = self.sag * self.length**2 / 4.0  # |n| at mid-length
        reach = max(self.widths) * np.hypot(1.0, self.sag * self.length)
        return _rotated_box(self.start, self.angle, (-reach, self.length + reach),
                            (min(0.0, -bend) - reach, max(0.0, -bend) + reach))

    def covers(self, x, y):
        t, n = _rotate(x - self.start[0], y - self.start[1], self.angle)
        centre = self.sag * t * (t - self.length)
        tangent = self.sag * (2.0 * t - self.length)  # dn/dt of the centre line
        width = self.widths[0] + (self.widths[1] - self.widths[0]) * t / self.length
        # Distance to a gently curved line ~ vertical offset / sqrt(1 + slope^2).
        return (t >= 0.0) & (t <= self.length) & (np.abs(n - centre) <= width * np.sqrt(1.0 + tangent * tangent))


@dataclass(frozen=True)
class _Grid:
    """Rotated rectangle of bars: a fence (bars along one axis) or a grid (both axes)."""

    centre: tuple
    half_axes: tuple
    angle: float
    periods: tuple
    bar_widths: tuple  # half width of the bars across each axis; 0: no bars

    @property
    def box(self):
        return _rotated_box(self.centre, self.angle, (-self.half_axes[0], self.half_axes[0]),
                            (-self.half_axes[1], self.half_axes[1]))

    def covers(self, x, y):
        u, v = _rotate(x - self.centre[0], y - self.centre[1], self.angle)
        inside = (np.abs(u) <= self.half_axes[0]) & (np.abs(v) <= self.half_axes[1])
        # Distance to the nearest bar centre: period * |w/period - round(w/period)|.
        on_u = np.abs(u - self.periods[0] * np.rint(u / self.periods[0])) <= self.bar_widths[0]
        on_v = np.abs(v - self.periods[1] * np.rint(v / self.periods[1])) <= self.bar_widths[1]
        return inside & (on_u | on_v)


# -------------------------------------------------------------------------------- appearance


@dataclass(frozen=True)
class _Paint:
    """Colour of a surface as a function of left-image coordinates.

    texel = frame @ (x - ox, y - oy) + offset; colour = base + (texture - mean) @ colour^T, times a
    smooth shading 1 + g . w - k |w|^2 with w the offset normalised by ``extent``.
    """

    texture: textures.Texture
    origin: tuple
    frame: np.ndarray
    offset: np.ndarray
    texels_per_pixel: float
    colour: np.ndarray
    base: np.ndarray
    shading: tuple  # (gx, gy, k)
    extent: tuple

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        dx = (x - self.origin[0]).astype(np.float32)
        dy = (y - self.origin[1]).astype(np.float32)
        frame = self.frame.astype(np.float32)
        # Texel coordinates: the 2x2 frame (rotation, scale, stretch) applied to the offset.
        u = frame[0, 0] * dx + frame[0, 1] * dy + np.float32(self.offset[0])
        v = frame[1, 0] * dx + frame[1, 1] * dy + np.float32(self.offset[1])
        centred = self.texture.sample(u, v, self.texels_per_pixel) - self.texture.mean
        # rgb = base + colour @ centred, written per input channel (a (N, 3) @ (3, 3) matmul is slower).
        rgb = self.base + centred[:, :1] * self.colour[:, 0] + centred[:, 1:2] * self.colour[:, 1] \
            + centred[:, 2:] * self.colour[:, 2]
        gx, gy, curvature = (np.float32(value) for value in self.shading)
        wx, wy = dx / np.float32(self.extent[0]), dy / np.float32(self.extent[1])
        shade = np.clip(1.0 + gx * wx + gy * wy - curvature * (wx * wx + wy * wy), 0.25, 1.5)
        return np.clip(rgb * shade[:, None], 0.0, 1.0)


def _pick(shares: dict, draw: float):
    """The key whose share interval holds ``draw`` in [0, 1) (inverse CDF of the shares)."""
    return list(shares)[int(np.searchsorted(np.cumsum(list(shares.values())), draw, side="right"))]


def _colour_matrix(contrast: float, saturation: float, hue_turn: float) -> np.ndarray:
    """RGB -> RGB: grey axis scaled by ``contrast``, chroma plane turned by ``hue_turn`` and scaled by
    ``contrast * saturation`` (in the orthonormal opponent basis)."""
    cos, sin = np.cos(hue_turn), np.sin(hue_turn)
    opponent = contrast * np.array([[1.0, 0.0, 0.0], [0.0, saturation * cos, -saturation * sin],
                                    [0.0, saturation * sin, saturation * cos]])
    # Change of basis: RGB -> opponent, transform, back (the basis is orthonormal: inverse = transpose).
    return (_OPPONENT.T @ opponent @ _OPPONENT).astype(np.float32)


class _Painter:
    """Draws the appearance of each surface from its own generator.

    Every call makes the same draws whether or not photographs are installed, so the photographs'
    presence changes colours but never the rest of the scene.
    """

    def __init__(self, rng: np.random.Generator, saturation: float):
        self.rng = rng
        self.photos = textures.available_photos()
        self.saturation = saturation

    def _texture(self) -> textures.Texture:
        rng = self.rng
        photo_draw, kind_draw, index_draw = rng.random(3)
        if self.photos and photo_draw < _PHOTO_SHARE:
            # Photo index = floor(draw * count): uniform over the installed photographs.
            return textures.photo(self.photos[int(index_draw * len(self.photos))])
        kind = _pick(_PROCEDURAL_SHARE, kind_draw)
        # Tile index = floor(draw * count): uniform over the tiles of the kind.
        return textures.procedural(kind, int(index_draw * textures.TILES_PER_KIND))

    def __call__(self, origin, extent, curved: bool, hard: float = 1.0) -> _Paint:
        """Paint of a surface centred at ``origin`` with half sizes ``extent``; ``hard`` scales the
        shares of textureless (7%) and low-contrast (15%) paints."""
        rng = self.rng
        texture = self._texture()
        photo = not texture.periodic
        upright, tilt, any_angle = rng.random(), rng.normal(0.0, 0.2), rng.uniform(0.0, 2 * np.pi)
        angle = tilt if photo and upright < 0.7 else any_angle
        scale = log_uniform(rng, 0.5, 3.0) if photo else log_uniform(rng, 0.3, 4.0)
        stretch = log_uniform(rng, 0.7, 1.4)
        cos, sin = np.cos(angle), np.sin(angle)
        # Rotation by angle, then the axes scaled by scale * stretch^(+-1/2).
        frame = np.array([[cos, sin], [-sin, cos]]) * (scale * np.array([[stretch**0.5], [stretch**-0.5]]))
        offset = rng.uniform(0.0, 1.0, 2) * np.array(texture.size[::-1])  # texel (u, v) anywhere in the image
        contrast_class, contrast_draw = rng.random(2)
        if contrast_class < 0.07 * hard:
            contrast = 0.02 * contrast_draw  # textureless
        elif contrast_class < 0.22 * hard:
            contrast = 0.04 + 0.16 * contrast_draw  # low contrast
        else:
            contrast = 0.6 + 0.7 * contrast_draw
        saturation = (rng.uniform(0.6, 1.2) if photo else rng.uniform(0.0, 1.3)) * self.saturation
        hue_turn = rng.normal(0.0, 0.15) if photo else rng.uniform(0.0, 2 * np.pi)
        grey = rng.uniform(0.08, 0.9)
        hue = rng.uniform(0.0, 2 * np.pi)
        chroma = rng.beta(1.2, 3.0) * 0.35 * self.saturation
        tint = chroma * (np.cos(hue) * _CHROMA[0] + np.sin(hue) * _CHROMA[1])
        gain = rng.uniform(0.6, 1.3)
        if photo:
            # A photograph keeps its own mean colour (brightened or darkened), slightly tinted.
            base = texture.mean * gain + 0.3 * tint
        else:
            base = grey + tint
        shading = (rng.normal(0.0, 0.15), rng.normal(0.0, 0.15), rng.uniform(0.1, 0.5) if curved else 0.0)
        return _Paint(
            texture=texture, origin=(float(origin[0]), float(origin[1])), frame=frame, offset=offset,
            texels_per_pixel=scale, colour=_colour_matrix(contrast, saturation, hue_turn),
            base=np.clip(base, 0.02, 0.98).astype(np.float32), shading=shading,
            extent=(max(float(extent[0]), 1.0), max(float(extent[1]), 1.0)),
        )


# ------------------------------------------------------------------------------- composition


@dataclass(frozen=True)
class _Surface:
    field: _Disparity
    shape: object  # _Region, _Ellipse, _Rectangle, _Blob, _Band or _Grid
    paint: _Paint
    kind: str
    box: tuple
    d_range: tuple

    def x_range(self, view: str) -> tuple[float, float]:
        """x interval of the surface in a view: right-view x = x - d, so it shifts by [-d_hi, -d_lo]."""
        if view == "left":
            return self.box[0], self.box[1]
        return self.box[0] - self.d_range[1], self.box[1] - self.d_range[0]


@dataclass(frozen=True)
class _Scene:
    height: int
    width: int
    surfaces: tuple
    cast: np.ndarray  # scene-wide colour of the light, (3,)


class _Composer:
    """Draws the surfaces of one scene (geometry from ``rng``, appearance from ``painter``)."""

    def __init__(self, rng: np.random.Generator, painter: _Painter, height: int, width: int, d_max: float):
        self.rng, self.painter = rng, painter
        self.height, self.width, self.d_max = height, width, d_max
        self.d_floor = _D_FLOOR * d_max
        self.size = min(height, width)
        # Left-image region that either view can see: the right view reaches x = W - 1 + d_max.
        self.reach = (-2.0, width + d_max + 2.0, -2.0, height + 1.0)
        self.surfaces: list[_Surface] = []

    def add(self, kind: str, shape, field: _Disparity, paint: _Paint, relative: float = 0.6) -> None:
        box = shape.box
        field = _fit(field, box, self.d_floor, self.d_max, relative)
        spread = field.spread(box)
        self.surfaces.append(_Surface(field=field, shape=shape, paint=paint, kind=kind, box=box,
                                      d_range=(field.c - spread, field.c + spread)))

    def field(self, centre, extent, d_centre: float, slant: float, curved: bool) -> _Disparity:
        """Disparity through ``d_centre`` at ``centre``, changing by up to ``slant * d_centre`` over
        ``extent`` (half sizes), plus a dome, cylinder or saddle when ``curved``."""
        rng = self.rng
        direction, amount = rng.uniform(0.0, 2 * np.pi), rng.uniform(0.0, slant)
        hu, hv = max(extent[0], 1.0), max(extent[1], 1.0)
        # Gradient of size amount * d / extent along the drawn direction.
        a = amount * d_centre * np.cos(direction) / hu
        b = amount * d_centre * np.sin(direction) / hv
        bend_x, bend_y, twist = rng.uniform(0.05, 0.35, 3) * d_centre
        form = rng.choice(["dome", "cylinder_x", "cylinder_y", "saddle"]) if curved else "plane"
        sign = -1.0 if rng.random() < 0.8 else 1.0  # mostly bulging towards the camera
        sx = {"dome": 1.0, "cylinder_x": 1.0, "cylinder_y": 0.0, "saddle": 1.0, "plane": 0.0}[form]
        sy = {"dome": 1.0, "cylinder_x": 0.0, "cylinder_y": 1.0, "saddle": -1.0, "plane": 0.0}[form]
        sxy = 0.3 if form == "dome" else 0.0
        # Curvature terms that change d by bend at the extent: q = bend / extent^2.
        return _Disparity(x0=float(centre[0]), y0=float(centre[1]), c=float(d_centre), a=float(a), b=float(b),
                          qxx=float(sign * sx * bend_x / hu**2), qxy=float(sign * sxy * twist / (hu * hv)),
                          qyy=float(sign * sy * bend_y / hv**2))

    def depth(self, low: float, high: float) -> float:
        """A disparity log-uniform in [low, high] * d_max (depth log-uniform: a long tail of near ones)."""
        return log_uniform(self.rng, low, high) * self.d_max

    def centre(self, d: float) -> tuple[float, float]:
        """A centre anywhere either view can see (the right view sees left x up to W - 1 + d)."""
        rng = self.rng
        # x in [-0.1 W, 1.1 W] plus up to d (what the right view adds), y in [-0.1 H, 1.1 H].
        return (float(rng.uniform(-0.1, 1.1) * self.width + rng.uniform(0.0, 1.0) * d),
                float(rng.uniform(-0.1, 1.1) * self.height))

    def background(self) -> float:
        rng = self.rng
        d_far = self.depth(0.008, 0.08)
        # Image centre; half sizes of the region both views see (the right view adds d_max in x).
        centre = ((self.width - 1) / 2, (self.height - 1) / 2)
        extent = (self.width / 2 + self.d_max, self.height / 2)
        field = self.field(centre, extent, d_far, 0.3, rng.random() < 0.2)
        self.add("background", _Region(self.reach), field, self.painter(centre, extent, False, hard=0.5), relative=0.5)
        return d_far

    def ground(self, d_far: float) -> None:
        rng = self.rng
        horizon = rng.uniform(0.25, 0.75) * self.height
        d_horizon = d_far * rng.uniform(1.0, 1.5)
        d_bottom = self.d_max * rng.uniform(0.15, 0.65)
        # The visible region below the horizon, and its centre.
        box = (self.reach[0], self.reach[1], horizon, self.reach[3])
        centre = ((self.width - 1) / 2, (horizon + self.height - 1) / 2)
        # Linear in y from d_horizon at the horizon to d_bottom at the last row; slight roll in x.
        b = (d_bottom - d_horizon) / max(self.height - 1 - horizon, 1.0)
        field = _Disparity(x0=centre[0], y0=centre[1], c=(d_horizon + d_bottom) / 2, a=rng.normal(0.0, 0.02),
                           b=float(b))
        extent = (self.width / 2, (self.height - horizon) / 2)  # half sizes of that region
        self.add("ground", _Region(box), field, self.painter(centre, extent, False, hard=0.5), relative=0.95)

    def wall(self) -> None:
        rng = self.rng
        d = self.depth(0.02, 0.35)
        half = tuple(rng.uniform(0.2, 0.6, 2) * np.array([self.width, self.height]))
        centre = self.centre(d)
        shape = _Rectangle(centre, half, float(rng.normal(0.0, 0.05)))
        field = self.field(centre, half, d, 0.9, False)
        self.add("wall", shape, field, self.painter(centre, half, False, hard=0.5), relative=0.9)

    def thing(self) -> None:
        rng = self.rng
        d = self.depth(0.03, 1.0)
        nearness = 0.5 + d / self.d_max  # nearer objects look larger
        radius = self.size * log_uniform(rng, 0.025, 0.22) * nearness
        aspect = log_uniform(rng, 1 / 3, 3.0)
        half = (radius * aspect**0.5, radius * aspect**-0.5)  # half axes with ratio aspect, geometric mean radius
        centre, angle = self.centre(d), float(rng.uniform(0.0, np.pi))
        kind_draw, curved = rng.random(), rng.random() < 0.45
        if kind_draw < 0.25:
            shape = _Ellipse(centre, half, angle)
        elif kind_draw < 0.5:
            shape = _Rectangle(centre, half, angle)
        else:
            orders = np.arange(2, 7)
            amplitudes = rng.uniform(0.0, 0.35, orders.size) / orders
            phases = rng.uniform(0.0, 2 * np.pi, orders.size)
            theta = np.arange(_BLOB_ANGLES) * (2 * np.pi / _BLOB_ANGLES)
            # Fourier-series radius: r(theta) = r0 (1 + sum_k a_k cos(k theta + phi_k)), kept above 0.3 r0.
            wobble = (amplitudes[:, None] * np.cos(orders[:, None] * theta + phases[:, None])).sum(axis=0)
            radii = half[1] * np.maximum(1.0 + wobble, 0.3)
            shape = _Blob(centre, radii, aspect, angle)
        field = self.field(centre, half, d, 0.5, curved)
        self.add("object", shape, field, self.painter(centre, half, curved))

    def stroke(self, kind: str, start, angle: float, length: float, sag: float, widths, field, paint) -> None:
        self.add(kind, _Band(start=(float(start[0]), float(start[1])), angle=float(angle), length=float(length),
                             sag=float(sag), widths=(float(widths[0]), float(widths[1]))), field, paint)

    def thin_width(self, d: float, scale: float = 1.0) -> float:
        """Half width of a thin structure (px), wider when near; at least 0.5 px, so that a stroke
        at any angle covers a pixel centre in every row or column it crosses."""
        width = log_uniform(self.rng, 0.5, 2.0) * (0.6 + d / self.d_max) * max(1.0, self.size / 256) ** 0.5
        return max(0.5, width * scale)

    def pole(self) -> None:
        rng = self.rng
        d = self.depth(0.03, 0.9)
        top = (float(rng.uniform(-0.1, 1.1) * self.width + rng.uniform(0.0, 1.0) * d),
               float(rng.uniform(-0.3, 0.4) * self.height))
        length = rng.uniform(0.4, 1.3) * self.height
        angle = np.pi / 2 + rng.normal(0.0, 0.08)  # pointing down, nearly vertical
        width = self.thin_width(d, rng.uniform(1.0, 2.5))
        # Mid-point: half the length along (cos angle, sin angle) from the top.
        middle = (top[0] + np.cos(angle) * length / 2, top[1] + np.sin(angle) * length / 2)
        field = self.field(middle, (width, length / 2), d, 0.4, rng.random() < 0.5)
        paint = self.painter(middle, (width, length / 2), True)
        self.stroke("pole", top, angle, length, 0.0, (width, max(0.5, width * rng.uniform(0.7, 1.0))), field, paint)

    def wire(self) -> None:
        rng = self.rng
        d = self.depth(0.03, 0.7)
        length = rng.uniform(0.6, 1.4) * (self.width + d)
        start = (float(rng.uniform(-0.2, 0.4) * self.width), float(rng.uniform(0.0, 0.8) * self.height))
        angle = rng.normal(0.0, 0.25)
        sag = rng.uniform(0.0, 0.25) * self.height / length**2 * 4  # mid-length sag up to a quarter height
        width = self.thin_width(d, rng.uniform(0.5, 1.0))
        # Mid-point: half the length along (cos angle, sin angle) from the start.
        middle = (start[0] + np.cos(angle) * length / 2, start[1] + np.sin(angle) * length / 2)
        field = self.field(middle, (length / 2, self.height / 4), d, 0.6, False)
        paint = self.painter(middle, (length / 2, width), False)
        # sag > 0 bends the middle to negative n, i.e. downwards for a left-to-right wire.
        self.stroke("wire", start, angle, length, -sag, (width, width), field, paint)

    def tree(self) -> None:
        rng = self.rng
        d = self.depth(0.03, 0.8)
        base = (float(rng.uniform(-0.1, 1.1) * self.width + rng.uniform(0.0, 1.0) * d),
                float(rng.uniform(0.7, 1.2) * self.height))
        length = rng.uniform(0.3, 0.8) * self.height
        width = self.thin_width(d, rng.uniform(1.5, 3.0))
        angle = -np.pi / 2 + rng.normal(0.0, 0.15)  # trunk pointing up
        middle = (base[0], base[1] - length / 2)  # about half the trunk above its base
        # One disparity field and one paint for the whole tree, so its strokes join seamlessly.
        field = self.field(middle, (length / 2, length / 2), d, 0.4, False)
        paint = self.painter(middle, (length / 2, length / 2), False)
        branches = [(base, angle, length, width, 0)]
        while branches:
            start, angle, length, width, level = branches.pop()
            bend = rng.normal(0.0, 0.15) / max(length, 1.0)
            self.stroke("branch", start, angle, length, bend, (width, max(0.5, width * 0.6)), field, paint)
            if level >= 2:
                continue
            for _ in range(int(rng.integers(2, 4))):
                at = rng.uniform(0.35, 0.95) * length
                # Branch point on the parent's straight chord, then a turn of 20-70 degrees either way.
                fork = (start[0] + np.cos(angle) * at, start[1] + np.sin(angle) * at)
                turn = rng.choice([-1.0, 1.0]) * rng.uniform(0.35, 1.2)
                child = (fork, angle + turn, length * rng.uniform(0.3, 0.65), max(width * 0.6, 0.5), level + 1)
                branches.append(child)

    def fence(self) -> None:
        rng = self.rng
        d = self.depth(0.04, 0.8)
        half = tuple(rng.uniform(0.15, 0.5, 2) * np.array([self.width, self.height]))
        centre = self.centre(d)
        period = rng.uniform(5.0, 20.0) * (0.6 + d / self.d_max)  # nearer fences look coarser
        bar = min(rng.uniform(0.5, 2.5), 0.35 * period)  # bars cover at most 70% of a period
        both = rng.random() < 0.5  # a grid; else a fence of bars across u only (half width -1: no v bars)
        periods = (period, period * log_uniform(rng, 0.6, 1.6))
        upright, any_angle = rng.random(), rng.uniform(0, np.pi)
        angle = float(rng.normal(0.0, 0.1) if upright < 0.7 else any_angle)
        shape = _Grid(centre, half, angle, periods, (bar, bar if both else -1.0))
        field = self.field(centre, half, d, 0.8, False)
        self.add("fence", shape, field, self.painter(centre, half, False))


def _compose(seed: int, height: int, width: int, d_max: float) -> tuple[_Scene, tuple]:
    """The scene of ``seed`` and the generators of its left and right cameras."""
    streams = np.random.SeedSequence(seed).spawn(4)
    geometry, look, left_camera, right_camera = (np.random.default_rng(stream) for stream in streams)
    painter = _Painter(look, saturation=look.uniform(0.4, 1.1))
    composer = _Composer(geometry, painter, height, width, d_max)
    # Counts grow with the square root of the image area (clipped to [0.6, 2] times the reference).
    crowd = float(np.clip(np.sqrt(height * width / _REFERENCE_AREA), 0.6, 2.0))
    d_far = composer.background()
    if geometry.random() < 0.55:
        composer.ground(d_far)
    for _ in range(int(geometry.integers(0, 4))):
        composer.wall()
    for _ in range(int(round(geometry.uniform(14, 40) * crowd))):
        composer.thing()
    thin = {composer.pole: 0.35, composer.wire: 0.3, composer.tree: 0.2, composer.fence: 0.15}
    for _ in range(int(round(geometry.integers(3, 11) * crowd))):
        _pick(thin, geometry.random())()
    cast = np.exp(look.normal(0.0, 0.08, 3)).astype(np.float32)  # colour of the light
    scene = _Scene(height=height, width=width, surfaces=tuple(composer.surfaces), cast=cast)
    return scene, (left_camera, right_camera)


# --------------------------------------------------------------------------------- rendering


def _front(surfaces, view: str, height: int, width: int, x_query: np.ndarray | None = None,
           shift: tuple[float, float] = (0.0, 0.0)):
    """Front-most surface per query point of a view; the query in row r lies on image row y = r.

    ``x_query`` None: the pixel grid (x = column), evaluated over each surface's window by slicing.
    Otherwise view-x coordinates per (row, column), and ``shift`` bounds ``column - x_query`` (the
    disparity range, for the right-view points of left pixels) so that each surface is evaluated
    only where it can be reached.

    Shapes
    ------
    x_query: (H, W); returns owner (H, W) int32 (-1: none), disparity (H, W) float64 (-inf: none),
    x_left (H, W) float64, the left-image x of the visible point.
    """
    best = np.full((height, width), -np.inf)
    owner = np.full((height, width), -1, dtype=np.int32)
    x_left = np.zeros((height, width))
    for index, surface in enumerate(surfaces):
        low, high = surface.x_range(view)
        row0, row1 = max(0, int(np.ceil(surface.box[2]))), min(height - 1, int(np.floor(surface.box[3])))
        # x_query in [low, high] and column - x_query in shift  =>  column in [low + shift0, high + shift1].
        col0 = max(0, int(np.ceil(low + shift[0])))
        col1 = min(width - 1, int(np.floor(high + shift[1])))
        if row0 > row1 or col0 > col1:
            continue
        if x_query is None:
            y = np.arange(row0, row1 + 1, dtype=np.float64)[:, None]
            x_view = np.broadcast_to(np.arange(col0, col1 + 1, dtype=np.float64), (row1 - row0 + 1, col1 - col0 + 1))
        else:
            band = x_query[row0:row1 + 1, col0:col1 + 1]
            rows, cols = np.nonzero((band >= low) & (band <= high))
            if rows.size == 0:
                continue
            x_view = band[rows, cols]
            rows += row0
            cols += col0
            y = rows.astype(np.float64)
        x = x_view
        if view == "right":
            x = surface.field.left_x(x_view, y)
            # No preimage on this field: move the point left of the box, where no shape covers.
            x = np.where(np.isnan(x), surface.box[0] - 1.0, x)
        disparity = surface.field(x, y)
        if x_query is None:
            window = (slice(row0, row1 + 1), slice(col0, col1 + 1))
            hit = surface.shape.covers(x, y) & (disparity > best[window])
            best[window][hit] = disparity[hit]
            owner[window][hit] = index
            x_left[window][hit] = x[hit]
        else:
            hit = surface.shape.covers(x, y) & (disparity > best[rows, cols])
            rows, cols = rows[hit], cols[hit]
            best[rows, cols] = disparity[hit]
            owner[rows, cols] = index
            x_left[rows, cols] = x[hit]
    return owner, best, x_left


def _shade(scene: _Scene, owner: np.ndarray, x_left: np.ndarray) -> np.ndarray:
    """Noise-free colours in [0, 1] of the visible surface points.

    Shapes
    ------
    owner, x_left: (H, W); return: (H, W, 3) float32.
    """
    height, width = owner.shape
    image = np.zeros((height * width, 3), dtype=np.float32)
    flat_owner = owner.ravel()
    order = np.argsort(flat_owner, kind="stable")
    # Slot 0 of the count is owner -1, slot i + 1 surface i: its pixels are order[ends[i]:ends[i + 1]].
    ends = np.cumsum(np.bincount(flat_owner + 1, minlength=len(scene.surfaces) + 1))
    flat_x = x_left.ravel()
    for index, surface in enumerate(scene.surfaces):
        pixels = order[ends[index]:ends[index + 1]]
        if pixels.size:
            # Row of a flat index: index // width.
            image[pixels] = surface.paint(flat_x[pixels], (pixels // width).astype(np.float64))
    return np.clip(image * scene.cast, 0.0, 1.0).reshape(height, width, 3)


def apply_camera(rng: np.random.Generator, image: np.ndarray,
                 noise_rng: np.random.Generator | None = None) -> np.ndarray:
    """One view's camera: exposure, white balance and vignetting (gains on linear light, applied as
    gain^(1/2.2) to the gamma-encoded image), slight blur, signal-dependent noise; uint8 out.
    ``noise_rng`` draws the noise itself (default ``rng``): a video keeps one camera (``rng`` in the same
    state every frame) with new noise each frame."""
    from ..stereo.filters import gaussian_blur

    height, width = image.shape[:2]
    exposure = np.exp(rng.normal(0.0, 0.1))
    white = np.exp(rng.normal(0.0, 0.03, 3))
    strength = rng.uniform(0.0, 0.35)
    centre = np.array([(width - 1) / 2, (height - 1) / 2]) + rng.normal(0.0, 0.05, 2) * [width, height]
    y, x = np.ogrid[:height, :width]
    # Vignetting 1 - k r^2, r = distance to the (jittered) optical centre over the half diagonal.
    radius2 = ((x - centre[0]) ** 2 + (y - centre[1]) ** 2) / (0.25 * (width**2 + height**2))
    vignette = (1.0 - strength * np.minimum(radius2, 2.0)) ** (1 / 2.2)
    gain = (exposure * white) ** (1 / 2.2)
    out = image * (vignette[..., None] * gain).astype(np.float32)
    sigma = rng.uniform(0.2, 0.8) if rng.random() < 0.6 else 0.0
    if sigma > 0:
        out = gaussian_blur(out, sigma)
    read, shot = log_uniform(rng, 0.002, 0.015), rng.uniform(0.0, 0.02)
    # Noise std sqrt(read^2 + shot^2 * signal): Gaussian approximation of Poisson-Gaussian noise.
    noise = (rng if noise_rng is None else noise_rng).standard_normal(out.shape, dtype=np.float32) \
        * np.sqrt(read**2 + shot**2 * np.clip(out, 0.0, 1.0))
    return _quantise(out + noise)


def _quantise(image: np.ndarray) -> np.ndarray:
    return np.rint(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)


def _render(scene: _Scene, cameras: tuple, clean: bool, layers: bool) -> dict:
    height, width = scene.height, scene.width
    owner_left, disparity, x_left = _front(scene.surfaces, "left", height, width)
    owner_right, _, x_left_right = _front(scene.surfaces, "right", height, width)
    x_right = np.arange(width) - disparity
    # Seen in the right view iff no surface at the right-view point is nearer than this one (the
    # surface itself gives the same disparity there, up to rounding).
    _, front, _ = _front(scene.surfaces, "right", height, width, x_query=x_right,
                         shift=(float(disparity.min()), float(disparity.max())))
    valid = (x_right >= 0) & (x_right <= width - 1) & (front <= disparity + 1e-6 * max(1.0, width))
    left = _shade(scene, owner_left, x_left)
    right = _shade(scene, owner_right, x_left_right)
    if clean:
        left, right = _quantise(left), _quantise(right)
    else:
        left, right = apply_camera(cameras[0], left), apply_camera(cameras[1], right)
    pair = {"left": left, "right": right, "disparity": disparity.astype(np.float32), "valid": valid}
    if layers:
        pair["surface_left"] = owner_left
        pair["surface_right"] = owner_right
        pair["surface_kind"] = tuple(surface.kind for surface in scene.surfaces)
    return pair


def make_scene(height: int, width: int, seed: int, *, max_disparity: float | None = None, clean: bool = False,
               layers: bool = False) -> dict:
    """A procedural rectified stereo pair with exact left disparity (see the module docstring).

    Parameters
    ----------
    height, width : int
        Image size (any positive size; the content is designed for 64 px and more).
    seed : int
        Non-negative scene seed; the pair is a deterministic function of (height, width, seed,
        max_disparity) and, for the colours only, of the photographs installed.
    max_disparity : float, optional
        Largest disparity in px, in (0, width]; default ``width / 4``.
    clean : bool
        True: no camera effects (both views share exposure, no vignetting, blur or noise), so a
        valid left pixel's colour is the right view's colour at ``(x - d, y)``.
    layers : bool
        True: also return the visible surface per pixel of each view and the surfaces' kinds.

    Returns
    -------
    dict
        ``left``, ``right``: uint8 RGB; ``disparity``: float32, exact at every left pixel centre, in
        (0, max_disparity]; ``valid``: bool, False where the left pixel is occluded in the right view
        or projects outside it. With ``layers``: ``surface_left``, ``surface_right`` (int32 surface
        index) and ``surface_kind`` (tuple of str: background, ground, wall, object, pole, wire,
        branch, fence).

    Shapes
    ------
    left, right: (H, W, 3); disparity, valid, surface_left, surface_right: (H, W).
    """
    height, width = check_size("make_scene", height, width)
    seed = check_seed("make_scene", seed)
    if max_disparity is None:
        d_max = width / 4.0
    else:
        d_max = float(max_disparity)
        if not (np.isfinite(d_max) and 0.0 < d_max <= width):
            raise ArgumentError(f"make_scene: max_disparity must be in (0, width={width}], got {max_disparity!r}")
    scene, cameras = _compose(seed, height, width, d_max)
    return _render(scene, cameras, clean, layers)


class SceneStereo(GeneratedStereo):
    """``n`` natural-statistics scenes of :func:`make_scene` (see :class:`GeneratedStereo` for the
    seeds, the held-out split and ``underwater``)."""

    name = "scenes"

    def generate(self, height: int, width: int, seed: int) -> dict:
        return make_scene(height, width, seed)

    def extra_meta(self) -> dict:
        return {"generator": GENERATOR_VERSION, "photo_sources": _SOURCES}
