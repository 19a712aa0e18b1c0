"""Stereo pairs made from single real photographs (the idea of Watson et al., "Learning Stereo from Single
Images", ECCV 2020), so that every pixel of texture, lighting and sensor noise a pair shows is real.

A pair is made in four steps, all a deterministic function of (height, width, seed) and the photographs:

1. **A photograph and a crop.** One photograph of the collection (:mod:`mipnet.data.photographs`), flipped
   at random, scaled and cropped to H x (W + margin): the margin holds what the right camera sees beyond
   the left view's right edge. Training seeds (below :data:`EVAL_SEED_START`) draw from the training
   photographs, evaluation and validation seeds from the held-out ones, so a validation set measures
   photographs the network never saw.
2. **A depth layout that follows the photograph's own edges.** Felzenszwalb's graph segmentation splits
   the image along its edges; adjacent segments of similar colour are merged into surfaces (a random
   threshold sets how coarse), and a surface with almost no texture (a blank wall, sky) joins the textured
   surface it shares the longest border with, so its disparity is one that texture reveals.
   Every surface gets a disparity field, a plane or a gently curved surface ``d = c + gx u + gy v + q (u^2 +
   v^2)`` about its centroid, slanted as a plane seen by a camera of focal length ``f = max(H, W)`` px at up
   to 63 degrees (``|gx|, |gy| <= 2 c / f``), keeping at least a quarter of ``c`` over the surface, with
   ``|dd/dx| <= 0.4``; often a scene prior places large surfaces touching the top border far away and those
   touching the bottom on a ground plane (disparity growing downwards from a horizon). The whole layout is
   then scaled so that its largest disparity is ``max_disparity`` at most (scaled, not clipped: no
   plateaus). Discontinuities of disparity therefore lie on edges of the photograph, as they do in real
   scenes, and occlusion order follows disparity.
3. **Both views rendered from the photograph.** The photograph is a surface texture in photo coordinates
   ``u``. The left view samples it at ``u = x + s`` for one random sub-pixel offset ``s`` per pair (so
   both views carry the blur of linear interpolation), its ground truth the surface's disparity there.
   The right view is a z-buffer over every stretch between neighbouring photo pixels of one surface
   (and across small steps of disparity between surfaces, as a camera's mixed pixels), each mapped to
   ``x_r = u - d(u) - s``: nearer surfaces hide farther ones exactly as in a real second camera. Where the right
   camera sees what the left one could not (disocclusions), another photograph's pixels fill in, as
   Watson et al. do, so the filled content is real but unmatched.
4. **Two cameras.** Each view gets its own exposure, white balance, vignetting, slight blur and sensor
   noise (:func:`mipnet.data.scenes.apply_camera`); water and the training augmentations come after, as
   for every generated pair.

``valid`` is False where the left pixel is hidden in the right view or falls outside it, and where it lies
more than :data:`_REVEAL_RADIUS` px from every textured pixel of the left view: inside a blank area the layout
is a guess that no view reveals (a white backdrop, a black sea), and a loss there would teach the guess.
"""

from __future__ import annotations

import numpy as np

from ..errors import ArgumentError
from . import photographs
from .scenes import apply_camera
from .synthetic import EVAL_SEED_START, GeneratedStereo, check_seed, check_size

__all__ = ["make_photo_pair", "PhotoStereo", "PHOTO_GENERATOR_VERSION"]

PHOTO_GENERATOR_VERSION = "photo-pairs-4"
_MAX_X_SLOPE = 0.4  # |dd/dx| bound of a surface: u -> u - d(u) stays increasing, stretch within [0.6, 1.4]
_MIXED_STEP = 1.0  # a disparity step of at most this many px between neighbouring surfaces renders as mixed pixels
_D_FLOOR = 0.25  # smallest disparity (px)
_MAX_TAN = 2.0  # steepest slant of a surface, tan 63 degrees: |dd/du| <= _MAX_TAN d / f, f the focal length (px)
_KEPT_SHARE = 0.25  # a slanted surface keeps at least this share of its centroid's disparity over its pixels
_REVEAL_RADIUS = 8.0  # a left pixel farther than this (px) from every textured pixel has no ground truth
_TEXTURE_STEP = 4.0 / 255.0  # a luminance step to a neighbour above this is texture (8-bit levels above JPEG noise)
_TEXTURED_SHARE = 0.1  # a group with fewer textured pixels than this is textureless
_STREAM = 0x5EED_F070  # the pair's random stream: default_rng([seed, _STREAM])


def _segments(image: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Felzenszwalb's segmentation of ``image`` at a random scale, and a coarse grouping of its segments into a
    few surfaces: adjacent segments merged in order of mean-colour distance (Kruskal) until 2-48 groups remain
    (log-uniform: from a few large surfaces to a cluttered scene with depth edges everywhere).

    Returns (H, W) segment labels 0..n-1 and each segment's group 0..g-1."""
    try:
        from skimage.segmentation import felzenszwalb
    except ImportError:
        raise ArgumentError("photo pairs need scikit-image for the segmentation: pip install 'mipnet[train]'") from None
    height, width = image.shape[:2]
    labels = felzenszwalb(image, scale=float(rng.uniform(50, 600)), sigma=float(rng.uniform(0.5, 1.0)),
                          min_size=int(max(16, height * width * rng.uniform(2e-4, 2e-3))))
    labels = np.unique(labels, return_inverse=True)[1].reshape(height, width)
    count = int(labels.max()) + 1
    sums = np.zeros((count, 3))
    np.add.at(sums, labels.ravel(), image.reshape(-1, 3))
    means = sums / np.maximum(np.bincount(labels.ravel(), minlength=count), 1)[:, None]
    # neighbouring label pairs across every horizontal and vertical pixel edge
    pairs = np.concatenate([np.stack([labels[:, :-1].ravel(), labels[:, 1:].ravel()], 1),
                            np.stack([labels[:-1].ravel(), labels[1:].ravel()], 1)])
    pairs = np.unique(np.sort(pairs[pairs[:, 0] != pairs[:, 1]], axis=1), axis=0)
    distance = np.linalg.norm(means[pairs[:, 0]] - means[pairs[:, 1]], axis=1)
    parent = np.arange(count)

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    groups, target = count, int(np.exp(rng.uniform(np.log(2), np.log(49))))
    for a, b in pairs[np.argsort(distance, kind="stable")]:
        if groups <= target:
            break
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
            groups -= 1
    group = np.unique([root(i) for i in range(count)], return_inverse=True)[1]
    return labels, _merge_textureless(image, labels, group)


def _textured_pixels(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose luminance changes by more than _TEXTURE_STEP to a horizontal or vertical
    neighbour (the cue a matcher can lock on; JPEG-smooth walls and sky stay below it)."""
    luma = image @ np.array([0.299, 0.587, 0.114])
    step = np.zeros(luma.shape)
    # a pixel's step: the larger of |I(x+1) - I(x)| and |I(y+1) - I(y)|, attributed to (y, x)
    step[:, :-1] = np.abs(np.diff(luma, axis=1))
    step[:-1] = np.maximum(step[:-1], np.abs(np.diff(luma, axis=0)))
    return step > _TEXTURE_STEP


def _revealed(image: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels within _REVEAL_RADIUS px of a textured pixel (none where nothing is textured)."""
    from scipy import ndimage

    textured = _textured_pixels(image)
    if not textured.any():
        return textured
    return ndimage.distance_transform_edt(~textured) <= _REVEAL_RADIUS


def _merge_textureless(image: np.ndarray, labels: np.ndarray, group: np.ndarray) -> np.ndarray:
    """``group`` with every textureless group (fewer than _TEXTURED_SHARE of its pixels textured) joined to the
    textured group it shares the longest border with, so that its disparity continues a surface whose texture
    shows it. A random plane of its own would be a disparity no view could reveal where it lies behind its
    neighbours (its borders then belong to them)."""
    grouped = group[labels]
    groups = int(group.max()) + 1
    share = np.bincount(grouped.ravel(), _textured_pixels(image).ravel(), groups) / np.maximum(
        np.bincount(grouped.ravel(), minlength=groups), 1)
    textured = share >= _TEXTURED_SHARE
    if textured.all() or not textured.any():
        return group
    # border length between groups a and b: the count of horizontal and vertical pixel edges from a to b
    pairs = np.concatenate([np.stack([grouped[:, :-1].ravel(), grouped[:, 1:].ravel()], 1),
                            np.stack([grouped[:-1].ravel(), grouped[1:].ravel()], 1)])
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    border = np.zeros((groups, groups))
    np.add.at(border, (pairs[:, 0], pairs[:, 1]), 1.0)
    border = (border + border.T) * textured[None, :]
    host = np.where(~textured & (border.max(axis=1) > 0), border.argmax(axis=1), np.arange(groups))
    return np.unique(host[group], return_inverse=True)[1]


def _centroids(labels: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel count and centroid (x, y) of each label."""
    v, u = np.indices(labels.shape)
    pixels = np.bincount(labels.ravel(), minlength=count).astype(np.float64)
    safe = np.maximum(pixels, 1.0)
    return pixels, np.bincount(labels.ravel(), u.ravel(), count) / safe, np.bincount(labels.ravel(), v.ravel(), count) / safe


class _Layout:
    """Per-segment disparity fields ``d_k(u, v) = c_k + gx_k (u - cx_k) + gy_k (v - cy_k) + q_k r^2`` with
    ``r^2 = (u - cx_k)^2 + (v - cy_k)^2``, over photo coordinates ``(u, v)``.

    A group's segments share its field (one smooth surface, whatever colour edges cross it), so disparity
    steps lie on the group boundaries and around the segments drawn as objects in front of their group."""

    def __init__(self, labels: np.ndarray, group: np.ndarray, rng: np.random.Generator, d_max: float):
        self.d_max = d_max
        focal = float(max(labels.shape))
        count, groups = len(group), int(group.max()) + 1
        grouped = group[labels]
        g_pixels, g_cx, g_cy = _centroids(grouped, groups)
        d_far = d_max * rng.uniform(0.005, 0.15)
        c = _base_disparities(grouped, g_pixels, rng, max(d_far, _D_FLOOR), d_max)
        gx, gy = c * _slants(rng, groups) / focal, c * _slants(rng, groups) / focal
        q = np.where(rng.random(groups) < 0.3, rng.normal(0.0, 1.6e-3, groups) * d_max / focal, 0.0)
        ground = np.zeros(groups, bool)
        if rng.random() < 0.6:
            ground = self._scene_prior(grouped, g_pixels, g_cy, (c, gx, gy, q), rng, d_far, d_max)
        g_reach = _reach(grouped, g_cx, g_cy)
        gx, gy, q = _keep_positive(g_reach, c, (gx, gy, q), exempt=ground)
        gx, q = _bound_slope(g_reach[0], gx, q)
        # every segment starts as a copy of its group's field
        self.cx, self.cy = g_cx[group], g_cy[group]
        self.c, self.gx, self.gy, self.q = c[group], gx[group], gy[group], q[group]
        # some segments of moderate size are objects in front of their group, with a plane of their own
        pixels, s_cx, s_cy = _centroids(labels, count)
        moderate = (pixels > 5e-4 * labels.size) & (pixels < 0.08 * labels.size)
        objects = moderate & (rng.random(count) < rng.uniform(0.0, 0.3))
        own_c = self.field(np.arange(count), s_cx, s_cy) * np.exp(rng.uniform(0.1, 0.8, count)) + 1.0
        s_reach = _reach(labels, s_cx, s_cy)
        own_gx, own_gy, own_q = _keep_positive(s_reach, own_c, (
            own_c * _slants(rng, count) / focal, own_c * _slants(rng, count) / focal, np.zeros(count)))
        own_gx, own_q = _bound_slope(s_reach[0], own_gx, own_q)
        self.cx, self.cy = np.where(objects, s_cx, self.cx), np.where(objects, s_cy, self.cy)
        self.c, self.gx = np.where(objects, own_c, self.c), np.where(objects, own_gx, self.gx)
        self.gy, self.q = np.where(objects, own_gy, self.gy), np.where(objects, own_q, self.q)
        # scale the whole layout (a shorter baseline) so that its largest disparity over the photograph is d_max
        v, u = np.indices(labels.shape)
        scale = min(1.0, d_max / float(self.field(labels, u, v).max()))
        self.c, self.gx, self.gy, self.q = self.c * scale, self.gx * scale, self.gy * scale, self.q * scale

    @staticmethod
    def _scene_prior(grouped, pixels, cy, fields, rng, d_far: float, d_max: float) -> np.ndarray:
        """Large groups touching the top border far away (sky, far walls), those touching the bottom border on
        one ground plane whose disparity grows linearly downwards from a horizon (in place). Returns the
        ground groups."""
        c, gx, gy, q = fields
        height = grouped.shape[0]
        large = pixels > 0.03 * grouped.size
        top, bottom = np.zeros(len(pixels), bool), np.zeros(len(pixels), bool)
        top[np.unique(grouped[0])] = True
        bottom[np.unique(grouped[-1])] = True
        far = large & top & ~bottom
        c[far] = d_far * rng.uniform(0.5, 1.5, far.sum())
        gx[far] *= 0.2
        gy[far] *= 0.2
        ground = large & bottom & ~top
        horizon = height * rng.uniform(0.1, 0.6)
        # the plane d = slope (v - horizon), slope = d_near / (H - 1 - horizon), written about each centroid
        slope = d_max * rng.uniform(0.3, 1.0) / max(height - 1 - horizon, 1.0)
        gy[ground] = slope
        c[ground] = np.maximum(slope * (cy[ground] - horizon), d_far)
        gx[ground] *= 0.2
        q[ground] = 0.0
        return ground

    def field(self, k: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The disparity of segment ``k`` at photo point ``(u, v)``, before the range's clip."""
        du, dv = u - self.cx[k], v - self.cy[k]
        return self.c[k] + self.gx[k] * du + self.gy[k] * dv + self.q[k] * (du * du + dv * dv)

    def __call__(self, k: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.clip(self.field(k, u, v), _D_FLOOR, self.d_max)


def _base_disparities(grouped: np.ndarray, pixels: np.ndarray, rng: np.random.Generator, d_low: float,
                      d_high: float) -> np.ndarray:
    """Each group's disparity at its centroid, correlated between neighbours as the parts of real objects are.

    The largest group draws log-uniformly in [d_low, d_high] (depth log-uniform); the others follow in
    breadth-first order over the groups' adjacency, each from the neighbour it was reached from: usually a
    small step (a crease or a slight depth change, ``log d`` moves by N(0, 0.08)), with probability 0.35 a
    depth discontinuity (``log d`` moves by up to +-1.2). Independent draws per group would cut every object
    into pieces at unrelated depths, each piece framed by occlusions."""
    groups = len(pixels)
    adjacent = np.zeros((groups, groups), bool)
    adjacent[grouped[:, :-1].ravel(), grouped[:, 1:].ravel()] = True
    adjacent[grouped[:-1].ravel(), grouped[1:].ravel()] = True
    adjacent |= adjacent.T
    log_d = np.full(groups, np.nan)
    start = int(np.argmax(pixels))
    log_d[start] = rng.uniform(np.log(d_low), np.log(d_high))
    queue = [start]
    while queue:
        parent = queue.pop(0)
        for child in np.flatnonzero(adjacent[parent] & np.isnan(log_d)):
            step = rng.uniform(-1.2, 1.2) if rng.random() < 0.35 else rng.normal(0.0, 0.08)
            log_d[child] = np.clip(log_d[parent] + step, np.log(d_low), np.log(d_high))
            queue.append(int(child))
    # groups not connected to the largest (none in a segmentation of one image) draw on their own
    unreached = np.isnan(log_d)
    log_d[unreached] = rng.uniform(np.log(d_low), np.log(d_high), int(unreached.sum()))
    return np.exp(log_d)


def _slants(rng: np.random.Generator, count: int) -> np.ndarray:
    """Random tangents of a surface's slant, in [-_MAX_TAN, _MAX_TAN], small ones more often."""
    return rng.uniform(-1.0, 1.0, count) * rng.uniform(0.0, _MAX_TAN, count)


def _reach(labels: np.ndarray, cx: np.ndarray, cy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The largest |u - cx| and |v - cy| over each label's pixels."""
    v, u = np.indices(labels.shape)
    flat = labels.ravel()
    reach_x, reach_y = np.zeros(len(cx)), np.zeros(len(cx))
    np.maximum.at(reach_x, flat, np.abs(u.ravel() - cx[flat]))
    np.maximum.at(reach_y, flat, np.abs(v.ravel() - cy[flat]))
    return reach_x, reach_y


def _keep_positive(reach: tuple[np.ndarray, np.ndarray], c: np.ndarray, slopes: tuple,
                   exempt: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(gx, gy, q)`` scaled so that each label's field stays above _KEPT_SHARE of its ``c`` over its pixels,
    whose extents about the label's centre are ``reach`` (:func:`_reach`): a slanted plane that reaches zero
    disparity would run to the horizon and be clipped flat there. The ``exempt`` labels (the ground plane, which
    does reach its horizon) are left as they are."""
    gx, gy, q = slopes
    reach_x, reach_y = reach
    # the field's lowest value over the label: c - |gx| reach_x - |gy| reach_y - |q| (reach_x^2 + reach_y^2)
    drop = np.abs(gx) * reach_x + np.abs(gy) * reach_y + np.abs(q) * (reach_x ** 2 + reach_y ** 2)
    scale = np.minimum(1.0, (1.0 - _KEPT_SHARE) * c / np.maximum(drop, 1e-12))
    if exempt is not None:
        scale = np.where(exempt, 1.0, scale)
    return gx * scale, gy * scale, q * scale


def _bound_slope(reach_x: np.ndarray, gx: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``gx`` and ``q`` scaled so that |dd/dx| = |gx + 2 q (u - cx)| <= _MAX_X_SLOPE over each label's pixels,
    whose largest |u - cx| is ``reach_x``."""
    scale = np.minimum(1.0, _MAX_X_SLOPE / np.maximum(np.abs(gx) + 2 * np.abs(q) * reach_x, 1e-12))
    return gx * scale, q * scale


def _render_right(photo: np.ndarray, labels: np.ndarray, layout: _Layout, width: int,
                  offset: float) -> tuple[np.ndarray, np.ndarray]:
    """The right view over columns 0..width-1 and its z-buffer disparity (-inf where nothing was seen).

    Both views share the sub-pixel ``offset`` s: left pixel x shows photo point u = x + s, right pixel x_r the
    point u with u - d(u) = x_r + s, so a point's two images lie d(u) apart, as the ground truth says."""
    height, span = labels.shape
    v, u = np.indices((height, span - 1))
    k0, k1 = labels[:, :-1], labels[:, 1:]
    d0 = layout(k0, u.astype(np.float64), v)
    d1 = layout(k1, u + 1.0, v)
    same = k0 == k1
    # one surface: both ends on it; across surfaces: a small step renders as mixed pixels, a large one is a hole
    d1 = np.where(same, layout(k0, u + 1.0, v), d1)
    rendered = same | (np.abs(d0 - d1) <= _MIXED_STEP)
    # the stretch between photo pixels u and u + 1 lands on right x in [a, b]: x_r = u - d(u) - s
    a, b = u - d0 - offset, u + 1.0 - d1 - offset
    cand_rows, cand_x, cand_d, cand_colour = [], [], [], []
    first = np.ceil(a)
    for step in range(3):  # b - a <= 1 + _MAX_X_SLOPE + _MIXED_STEP < 3
        x = first + step
        keep = rendered & (x <= b) & (b > a) & (x >= 0) & (x <= width - 1)
        # t in [0, 1]: the position of x_r within the stretch, linear in photo coordinates
        t = ((x - a) / np.where(b > a, b - a, 1.0))[keep]
        rows, cols = v[keep], u[keep]
        cand_rows.append(rows)
        cand_x.append(x[keep].astype(np.int64))
        cand_d.append((1 - t) * d0[keep] + t * d1[keep])
        cand_colour.append((1 - t)[:, None] * photo[rows, cols] + t[:, None] * photo[rows, cols + 1])
    rows, xs = np.concatenate(cand_rows), np.concatenate(cand_x)
    disparity, colour = np.concatenate(cand_d), np.concatenate(cand_colour)
    # z-buffer: per right pixel the candidate of largest disparity (nearest), found by sorting
    flat = rows * width + xs
    order = np.lexsort((disparity, flat))
    last = np.r_[flat[order][1:] != flat[order][:-1], True]
    winners = order[last]
    right = np.zeros((height * width, 3), np.float32)
    zbuffer = np.full(height * width, -np.inf)
    right[flat[winners]] = colour[winners]
    zbuffer[flat[winners]] = disparity[winners]
    return right.reshape(height, width, 3), zbuffer.reshape(height, width)


def _photo_crop(rng: np.random.Generator, height: int, span: int, held_out: bool) -> tuple[np.ndarray, str]:
    """A random photograph of the split, flipped at random, scaled and cropped to (height, span), float32 in
    [0, 1]."""
    from PIL import Image

    names = photographs.names(held_out=held_out)
    if not names:
        split = "held-out" if held_out else "training"
        raise ArgumentError(f"photo pairs: no {split} photographs are installed; pip install 'mipnet[train]' "
                            f"(see mipnet.data.photographs)")
    name = names[int(rng.integers(len(names)))]
    image = photographs.load(name)
    if rng.random() < 0.5:
        image = image.transpose(Image.FLIP_LEFT_RIGHT)
    w0, h0 = image.size
    # the crop covers (height, span) after scaling by f: at least the whole crop, at most 1.6x zoom-in
    f_min = max(height / h0, span / w0)
    f = f_min * np.exp(rng.uniform(0.0, np.log(1.6))) if f_min < 1 else f_min
    cw, ch = span / f, height / f
    x0, y0 = rng.uniform(0, max(w0 - cw, 0)), rng.uniform(0, max(h0 - ch, 0))
    crop = image.resize((span, height), Image.BILINEAR, box=(x0, y0, x0 + cw, y0 + ch), reducing_gap=3.0)
    return np.asarray(crop, dtype=np.float32) / 255.0, name


def make_photo_pair(height: int, width: int, seed: int, *, max_disparity: float | None = None,
                    clean: bool = False) -> dict:
    """A rectified stereo pair made from one real photograph (see the module docstring).

    Parameters
    ----------
    height, width : int
        Image size (the content is designed for 64 px and more).
    seed : int
        Non-negative pair seed; seeds below :data:`EVAL_SEED_START` draw training photographs, seeds from it
        on held-out ones.
    max_disparity : float, optional
        Largest disparity in px, in (0, width]; default ``width / 4``.
    clean : bool
        True: no camera effects, so a valid left pixel's colour matches the right view at ``(x - d, y)`` up to
        interpolation.

    Returns
    -------
    dict
        ``left``, ``right``: uint8 RGB; ``disparity``: float32 left-view disparity in
        [0.25, max_disparity]; ``valid``: bool; ``meta``: the photograph's name and the generator version.

    Shapes
    ------
    left, right: (H, W, 3); disparity, valid: (H, W).
    """
    height, width = check_size("make_photo_pair", height, width)
    seed = check_seed("make_photo_pair", seed)
    d_max = width / 4.0 if max_disparity is None else float(max_disparity)
    if not (np.isfinite(d_max) and 0.0 < d_max <= width):
        raise ArgumentError(f"make_photo_pair: max_disparity must be in (0, width={width}], got {max_disparity!r}")
    rng = np.random.default_rng([seed, _STREAM])
    span = width + int(np.ceil(d_max)) + 2
    photo, name = _photo_crop(rng, height, span, held_out=seed >= EVAL_SEED_START)
    labels, group = _segments(photo, rng)
    layout = _Layout(labels, group, rng, d_max)
    offset = float(rng.uniform(0.0, 1.0))
    rows, cols = np.indices((height, width))
    u = cols + offset
    # the left pixel x shows photo point u = x + s: colour linear between u's neighbours, surface of the nearer
    left = (1 - offset) * photo[:, :width] + offset * photo[:, 1:width + 1]
    owner = labels[rows, np.rint(u).astype(np.int64)]
    disparity = layout(owner, u, rows)
    right, zbuffer = _render_right(photo, labels, layout, width, offset)
    holes = ~np.isfinite(zbuffer)
    if holes.any():
        filler, _ = _photo_crop(rng, height, width, held_out=seed >= EVAL_SEED_START)
        right[holes] = filler[holes]
    # seen in the right view: x - d inside it, and no nearer surface at round(x - d)
    x_right = cols - disparity
    inside = (x_right >= 0) & (x_right <= width - 1)
    nearest = np.clip(np.rint(x_right), 0, width - 1).astype(np.int64)
    valid = inside & (zbuffer[rows, nearest] <= disparity + 0.5) & _revealed(left)
    if clean:
        left8, right8 = (np.rint(np.clip(v, 0, 1) * 255).astype(np.uint8) for v in (left, right))
    else:
        left8, right8 = apply_camera(rng, left), apply_camera(rng, right)
    return {"left": left8, "right": right8, "disparity": disparity.astype(np.float32), "valid": valid,
            "meta": {"photo": name, "generator": PHOTO_GENERATOR_VERSION}}


class PhotoStereo(GeneratedStereo):
    """``n`` pairs of :func:`make_photo_pair` (see :class:`GeneratedStereo` for the seeds, the held-out split
    and ``underwater``)."""

    name = "photos"

    def generate(self, height: int, width: int, seed: int) -> dict:
        return make_photo_pair(height, width, seed)

    def extra_meta(self) -> dict:
        return {"generator": PHOTO_GENERATOR_VERSION, "photographs": photographs.sources()}

