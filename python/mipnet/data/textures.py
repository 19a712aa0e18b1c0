"""Texture sources of :mod:`mipnet.data.scenes`: procedural tiles with natural-image statistics, and
photographs that ship inside optional packages.

Procedural tiles (always available): 256 x 256 RGB, periodic, generated lazily from fixed seeds and
cached (``TILES_PER_KIND`` of each kind), so a scene picks a tile by index and maps it onto a surface
with its own rotation, scale, offset and colour transform.

* ``pink``: Gaussian noise with a 1/f^alpha amplitude spectrum (alpha 0.8-1.4; natural images have
  alpha near 1), sometimes anisotropic (grain), a luminance field plus weaker chroma fields.
* ``leaves``: the dead-leaves occlusion model (Matheron; Lee, Mumford and Huang 2001): discs with a
  radius density proportional to r^-3 dropped one in front of the other, which gives the
  scale-invariant, occlusion-dominated statistics of natural images; colours drawn around a random
  mean with a random spread (often muted), sometimes with fine pink-noise detail inside the discs.
* ``periodic``: stripes, checkers, bricks and dot lattices whose period divides the tile size (the
  repetitive regions on which matching is ambiguous), with a little pink noise.

Photographs (only where the package is installed, e.g. ``pip install mipnet[train]``; none is a
runtime dependency). Each is read from the package's own files with Pillow, never downloaded. The
list, with the licence each package states for it:

=====================  ==========================  ==============================================
package                file                        licence (as stated by the package)
=====================  ==========================  ==============================================
scikit-image           data/astronaut.png          public domain (NASA, Eileen Collins)
scikit-image           data/brick.png              CC0 (CC0Textures "Bricks25")
scikit-image           data/camera.png             CC0 (photographer Lav Varshney)
scikit-image           data/cell.png               CC0 (qpformat phase image)
scikit-image           data/chelsea.png            CC0 (photographer Stefan van der Walt)
scikit-image           data/clock_motion.png       public domain (photographer Stefan van der Walt)
scikit-image           data/coffee.png             CC0 (photographer Rachel Michetti)
scikit-image           data/coins.png              no known copyright restrictions (Brooklyn Museum)
scikit-image           data/grass.png              CC0 (DeviantArt "Grass 01", linolafett)
scikit-image           data/gravel.png             CC0 (CC0Textures "Gravel04")
scikit-image           data/hubble_deep_field.jpg  public domain (NASA)
scikit-image           data/ihc.png                no known copyright restrictions (CMMI)
scikit-image           data/retina.jpg             CC0 (Mikael Haggstrom, Wikimedia Commons)
scikit-image           data/rocket.jpg             public domain (SpaceX)
scikit-learn           datasets/images/china.jpg   CC BY 2.0, attribution: danielbuechele (Flickr)
scikit-learn           datasets/images/flower.jpg  CC BY 2.0, attribution: vultilion (Flickr)
matplotlib             mpl-data/sample_data/       public domain (U.S. Navy photograph of
                       grace_hopper.jpg            Grace Hopper)
=====================  ==========================  ==============================================

Left out on purpose: scikit-image's ``motorcycle_*`` (a Middlebury stereo pair: evaluation data),
images without a stated licence (``moon``, ``page``, matplotlib's ``Minduka_Present_Blue_Pack``),
drawings and synthetic images (``text``, ``logo``, ``horse``, ``phantom``, ``color``, chessboards).
"""

from __future__ import annotations

import functools
import importlib.metadata
import importlib.util
import os
from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError

__all__ = ["Texture", "PHOTOS", "PROCEDURAL_KINDS", "TILES_PER_KIND", "CHROMA_AXES", "photo_sources",
           "available_photos", "photo", "procedural"]

TILE_SIZE = 256  # procedural tile side (px); every period used divides it, so tiles wrap seamlessly
TILES_PER_KIND = 24
PROCEDURAL_KINDS = ("pink", "leaves", "periodic")
_PHOTO_MAX_SIDE = 512  # larger photographs are reduced to this on loading
_MIN_LEVEL_SIDE = 16  # the coarsest mip level keeps at least this many pixels per side
_TILE_SEED = 0x7E57  # root of the tiles' seeds: tile (kind, index) is a fixed function of them
# Two orthonormal RGB directions orthogonal to grey (red-green, yellow-blue).
CHROMA_AXES = np.array([[1.0, -1.0, 0.0], [1.0, 1.0, -2.0]]) / np.sqrt([[2.0], [6.0]])

# (distribution name, import name, path inside the package, short name, licence)
PHOTOS: tuple[tuple[str, str, str, str, str], ...] = (
    ("scikit-image", "skimage", "data/astronaut.png", "astronaut", "public domain (NASA)"),
    ("scikit-image", "skimage", "data/brick.png", "brick", "CC0"),
    ("scikit-image", "skimage", "data/camera.png", "camera", "CC0"),
    ("scikit-image", "skimage", "data/cell.png", "cell", "CC0"),
    ("scikit-image", "skimage", "data/chelsea.png", "chelsea", "CC0"),
    ("scikit-image", "skimage", "data/clock_motion.png", "clock", "public domain"),
    ("scikit-image", "skimage", "data/coffee.png", "coffee", "CC0"),
    ("scikit-image", "skimage", "data/coins.png", "coins", "no known copyright restrictions"),
    ("scikit-image", "skimage", "data/grass.png", "grass", "CC0"),
    ("scikit-image", "skimage", "data/gravel.png", "gravel", "CC0"),
    ("scikit-image", "skimage", "data/hubble_deep_field.jpg", "hubble", "public domain (NASA)"),
    ("scikit-image", "skimage", "data/ihc.png", "ihc", "no known copyright restrictions"),
    ("scikit-image", "skimage", "data/retina.jpg", "retina", "CC0"),
    ("scikit-image", "skimage", "data/rocket.jpg", "rocket", "public domain (SpaceX)"),
    ("scikit-learn", "sklearn", "datasets/images/china.jpg", "china", "CC BY 2.0 (danielbuechele)"),
    ("scikit-learn", "sklearn", "datasets/images/flower.jpg", "flower", "CC BY 2.0 (vultilion)"),
    ("matplotlib", "matplotlib", "mpl-data/sample_data/grace_hopper.jpg", "grace_hopper", "public domain (U.S. Navy)"),
)


@dataclass(frozen=True)
class Texture:
    """An RGB image pyramid to sample with bilinear interpolation.

    Attributes
    ----------
    levels : tuple of numpy.ndarray
        uint32 images, each pixel's R, G, B in its first three bytes (one gather per texel); level
        k is the base image reduced 2^k times (2x2 box filter).
    mean : numpy.ndarray
        Mean colour of the base level in [0, 1], float32.
    periodic : bool
        True: coordinates wrap around (seamless tiles); False: mirrored repetition (photographs).
    name : str
        ``kind:index`` or the photograph's name.

    Shapes
    ------
    levels[k]: (H / 2^k, W / 2^k); mean: (3,).
    """

    levels: tuple
    mean: np.ndarray
    periodic: bool
    name: str

    @property
    def size(self) -> tuple[int, int]:
        """(height, width) of the base level."""
        return self.levels[0].shape

    def sample(self, u: np.ndarray, v: np.ndarray, texels_per_pixel: float) -> np.ndarray:
        """Colours in [0, 1] at base-level texel coordinates (u, v) (x right, y down).

        ``texels_per_pixel`` (how many base texels one image pixel spans) picks the mip level, so
        a minified texture is prefiltered rather than aliased.

        Shapes
        ------
        u, v: (N,); return: (N, 3) float32.
        """
        # Level k halves the resolution k times; use the finest level with at most ~1 texel per pixel.
        level = int(np.clip(np.floor(np.log2(max(texels_per_pixel, 1.0))), 0, len(self.levels) - 1))
        scale = 0.5**level
        return _bilinear(self.levels[level], u * scale, v * scale, self.periodic)


def _wrap(index: np.ndarray, length: int, periodic: bool) -> np.ndarray:
    if periodic:
        return index % length
    # Mirrored repetition: period 2n, the second half read backwards.
    folded = index % (2 * length)
    return np.where(folded < length, folded, 2 * length - 1 - folded)


def _bilinear(packed: np.ndarray, u: np.ndarray, v: np.ndarray, periodic: bool) -> np.ndarray:
    """Bilinear interpolation of a packed RGB image at (u, v), pixel centres at integer coordinates."""
    height, width = packed.shape
    u0 = np.floor(u)
    v0 = np.floor(v)
    fu = (u - u0).astype(np.float32)[:, None]
    fv = (v - v0).astype(np.float32)[:, None]
    iu, iv = u0.astype(np.int64), v0.astype(np.int64)
    i0, i1 = _wrap(iu, width, periodic), _wrap(iu + 1, width, periodic)
    # Row offsets into the flattened image: j * width.
    j0, j1 = _wrap(iv, height, periodic) * width, _wrap(iv + 1, height, periodic) * width
    flat = packed.ravel()

    def corner(index):
        return flat[index].view(np.uint8).reshape(-1, 4)[:, :3].astype(np.float32)

    top_left, bottom_left = corner(j0 + i0), corner(j1 + i0)
    top = top_left + fu * (corner(j0 + i1) - top_left)
    bottom = bottom_left + fu * (corner(j1 + i1) - bottom_left)
    return (top + fv * (bottom - top)) * np.float32(1.0 / 255.0)


def _pyramid(image: np.ndarray) -> tuple:
    """uint8 RGB mip levels of a float [0, 1] or uint8 RGB image (2x2 box filter per level)."""
    base = np.asarray(image, dtype=np.float32)
    if np.issubdtype(np.asarray(image).dtype, np.integer):
        base = base / 255.0
    levels = [base]
    while min(levels[-1].shape[:2]) >= 2 * _MIN_LEVEL_SIDE:
        current = levels[-1]
        # Even crop, then the mean of each 2x2 block.
        h, w = (current.shape[0] // 2) * 2, (current.shape[1] // 2) * 2
        blocks = current[:h, :w].reshape(h // 2, 2, w // 2, 2, 3)
        levels.append(blocks.mean(axis=(1, 3)))
    return tuple(np.rint(np.clip(level, 0.0, 1.0) * 255).astype(np.uint8) for level in levels)


def _pack(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 -> (H, W) uint32 with R, G, B in the first three bytes (native byte order)."""
    padded = np.concatenate([image, np.zeros(image.shape[:2] + (1,), dtype=np.uint8)], axis=2)
    return np.ascontiguousarray(padded).view(np.uint32)[..., 0]


def _texture(image: np.ndarray, periodic: bool, name: str) -> Texture:
    levels = _pyramid(image)
    mean = (levels[0].reshape(-1, 3).mean(axis=0) / 255.0).astype(np.float32)
    return Texture(levels=tuple(_pack(level) for level in levels), mean=mean, periodic=periodic, name=name)


# ------------------------------------------------------------------------------- photographs


def _package_dir(import_name: str) -> str | None:
    """Folder of an installed package, found without importing it (None: not installed)."""
    try:
        spec = importlib.util.find_spec(import_name)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return list(spec.submodule_search_locations)[0]


def photo_path(import_name: str, relative: str) -> str | None:
    """The file ``relative`` inside the installed package ``import_name`` (None: not installed)."""
    folder = _package_dir(import_name)
    if folder is None:
        return None
    path = os.path.join(folder, *relative.split("/"))
    return path if os.path.isfile(path) else None


@functools.lru_cache(maxsize=None)
def available_photos() -> tuple[str, ...]:
    """Names (see ``PHOTOS``) of the photographs whose files are installed here, in ``PHOTOS`` order."""
    return tuple(name for _, module, relative, name, _ in PHOTOS if photo_path(module, relative) is not None)


@functools.lru_cache(maxsize=None)
def photo_sources() -> tuple[str, ...]:
    """``distribution-version`` of each package that provides at least one photograph here."""
    found = []
    for distribution, module, relative, _, _ in PHOTOS:
        if photo_path(module, relative) is None:
            continue
        try:
            label = f"{distribution}-{importlib.metadata.version(distribution)}"
        except importlib.metadata.PackageNotFoundError:
            label = distribution
        if label not in found:
            found.append(label)
    return tuple(found)


@functools.lru_cache(maxsize=None)
def photo(name: str) -> Texture:
    """The photograph ``name`` (one of :func:`available_photos`) as a mirrored-repeat texture.

    Grey photographs become three equal channels; sides above 512 px are reduced to 512.
    """
    entries = {entry[3]: entry for entry in PHOTOS}
    path = photo_path(entries[name][1], entries[name][2]) if name in entries else None
    if path is None:
        raise ArgumentError(f"photo: {name!r} is not an installed photograph; available: {list(available_photos())}")
    return _texture(np.asarray(read_photo(path, _PHOTO_MAX_SIDE)), periodic=False, name=name)


def read_photo(path: str, max_side: int):
    """The image file at ``path`` as an RGB ``PIL.Image`` (grey becomes three equal channels), reduced so that
    its longer side is at most ``max_side`` (box filter, aspect ratio kept)."""
    from PIL import Image

    with Image.open(path) as opened:
        image = opened.convert("RGB")
    reduction = max(image.size) / max_side
    if reduction > 1:
        image = image.resize((round(image.size[0] / reduction), round(image.size[1] / reduction)), Image.BOX)
    return image


# ------------------------------------------------------------------------------- procedural


def _opponent_basis() -> np.ndarray:
    """Rows: the grey axis (scaled so a grey amplitude g gives RGB (g, g, g)) and the chroma axes."""
    return np.vstack([np.ones(3), CHROMA_AXES])


def _pink_field(rng: np.random.Generator, size: int, alpha: float, stretch: float, angle: float) -> np.ndarray:
    """Zero-mean, unit-std periodic Gaussian field with amplitude spectrum |f'|^-alpha.

    f' is the frequency rotated by ``angle`` with its second component scaled by ``stretch``
    (stretch > 1: structures elongated along the rotated first axis).
    """
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    cos, sin = np.cos(angle), np.sin(angle)
    # Rotate the frequency vector, then stretch its second component.
    fu, fv = cos * fx + sin * fy, (-sin * fx + cos * fy) * stretch
    radius = np.hypot(fu, fv)
    radius[0, 0] = np.inf  # drop the mean (DC) term
    amplitude = radius**-alpha
    field = np.fft.irfft2(np.fft.rfft2(rng.standard_normal((size, size))) * amplitude, s=(size, size))
    return (field - field.mean()) / max(field.std(), 1e-12)


def _pink_tile(rng: np.random.Generator, size: int) -> np.ndarray:
    alpha = rng.uniform(0.8, 1.4)
    stretch = rng.choice([1.0, rng.uniform(1.5, 6.0)], p=[0.7, 0.3])
    angle = rng.uniform(0, np.pi)
    luminance = _pink_field(rng, size, alpha, stretch, angle)
    if rng.random() < 0.3:
        # Blotchy variant: a soft threshold turns the field into stone- or camouflage-like patches.
        sharpness = rng.uniform(1.5, 4.0)
        luminance = np.tanh(sharpness * luminance) / np.tanh(sharpness)
    chroma = [_pink_field(rng, size, alpha + rng.uniform(0.0, 0.5), stretch, angle) for _ in range(2)]
    weights = np.array([rng.uniform(0.12, 0.2), *rng.uniform(0.0, 0.08, 2)])
    fields = np.stack([luminance, *chroma], axis=-1) * weights
    # Opponent (grey, chroma1, chroma2) amplitudes -> RGB around mid-grey.
    return 0.5 + fields @ _opponent_basis()


def _dead_leaves_tile(rng: np.random.Generator, size: int) -> np.ndarray:
    r_min, r_max = rng.uniform(1.0, 2.5), size / rng.uniform(4.0, 8.0)
    # E[r^2] for density 2 r^-3 / (r_min^-2 - r_max^-2) on [r_min, r_max] is 2 ln(r_max/r_min) / (r_min^-2 - r_max^-2).
    mean_area = np.pi * 2.0 * np.log(r_max / r_min) / (r_min**-2 - r_max**-2)
    count = int(4.0 * size * size / mean_area)  # about four layers deep: exp(-4) of the tile shows the base
    # Inverse CDF of the r^-3 density: r = (r_min^-2 - u (r_min^-2 - r_max^-2))^-1/2.
    radius = (r_min**-2 - rng.random(count) * (r_min**-2 - r_max**-2)) ** -0.5
    centre = rng.uniform(0, size, (count, 2))
    # Opponent (grey, chroma, chroma) mean and spread of the leaves' colours.
    mean = rng.uniform(0.25, 0.75) * np.array([1.0, 0.0, 0.0]) + rng.normal(0.0, 0.06, 3) * [0.0, 1.0, 1.0]
    spread = np.array([rng.uniform(0.08, 0.25), *np.full(2, rng.uniform(0.01, 0.12))])
    colours = (mean + rng.normal(0.0, 1.0, (count, 3)) * spread) @ _opponent_basis()
    owner = np.full(size * size, -1, dtype=np.int64)
    whole = np.ceil(radius).astype(np.int64)
    for reach in np.unique(whole):
        members = np.nonzero(whole == reach)[0]
        dy, dx = np.mgrid[-reach:reach + 1, -reach:reach + 1].reshape(2, 1, -1)
        # Pixels (integer centres) of each disc's bounding square, relative to its centre.
        px = np.floor(centre[members, 0])[:, None] + dx
        py = np.floor(centre[members, 1])[:, None] + dy
        distance2 = (px - centre[members, 0, None]) ** 2 + (py - centre[members, 1, None]) ** 2
        inside = distance2 <= radius[members, None] ** 2
        # Flat index of the wrapped pixel: (y mod size) * size + (x mod size).
        flat = (py.astype(np.int64) % size) * size + px.astype(np.int64) % size
        order = np.broadcast_to(members[:, None], flat.shape)
        np.maximum.at(owner, flat[inside], order[inside])  # the later (front) disc wins
    image = np.where((owner >= 0)[:, None], colours[np.maximum(owner, 0)], mean @ _opponent_basis())
    image = image.reshape(size, size, 3)
    if rng.random() < 0.5:
        image = image * (1.0 + rng.uniform(0.05, 0.2) * _pink_field(rng, size, 1.0, 1.0, 0.0))[..., None]
    return image


def _periodic_tile(rng: np.random.Generator, size: int) -> np.ndarray:
    y, x = np.indices((size, size), dtype=np.float64)
    period_x, period_y = (float(2 ** rng.integers(2, 7)) for _ in range(2))
    pattern = rng.choice(["stripes", "checker", "bricks", "dots"])
    sharpness = rng.uniform(0.5, 6.0)
    if pattern == "stripes":
        wave = np.sin(2 * np.pi * x / period_x)
    elif pattern == "checker":
        wave = np.sin(2 * np.pi * x / period_x) * np.sin(2 * np.pi * y / period_y)
    elif pattern == "bricks":
        row = np.floor(y / period_y)
        # Odd brick rows shift by half a brick; mortar where x or y is near a brick boundary.
        u = (x + 0.5 * period_x * (row % 2)) % period_x
        v = y % period_y
        mortar = np.minimum(np.minimum(u, period_x - u), np.minimum(v, period_y - v))
        wave = np.where(mortar < rng.uniform(0.5, 0.15 * min(period_x, period_y) + 0.5), -1.0, 1.0)
    else:
        # Distance to the nearest lattice point, in periods.
        du = (x / period_x) - np.round(x / period_x)
        dv = (y / period_y) - np.round(y / period_y)
        wave = np.where(np.hypot(du, dv) < rng.uniform(0.15, 0.4), 1.0, -1.0)
    level = 0.5 + 0.5 * np.tanh(sharpness * wave) / np.tanh(sharpness)
    first, second = rng.uniform(0.0, 1.0, (2, 3)) * rng.uniform(0.3, 1.0) + rng.uniform(0.0, 0.3)
    image = first + (second - first) * level[..., None]
    return image + rng.uniform(0.02, 0.08) * _pink_field(rng, size, 1.0, 1.0, 0.0)[..., None]


_GENERATORS = {"pink": _pink_tile, "leaves": _dead_leaves_tile, "periodic": _periodic_tile}


@functools.lru_cache(maxsize=None)
def procedural(kind: str, index: int) -> Texture:
    """Procedural tile ``index`` (0 <= index < ``TILES_PER_KIND``) of ``kind`` (``PROCEDURAL_KINDS``).

    A fixed function of (kind, index), generated on first use and cached.
    """
    if kind not in _GENERATORS or not 0 <= int(index) < TILES_PER_KIND:
        raise ArgumentError(
            f"procedural: need kind in {PROCEDURAL_KINDS} and 0 <= index < {TILES_PER_KIND}, got {kind!r}, {index}"
        )
    rng = np.random.default_rng([_TILE_SEED, PROCEDURAL_KINDS.index(kind), int(index)])
    return _texture(_GENERATORS[kind](rng, TILE_SIZE), periodic=True, name=f"{kind}:{index}")
