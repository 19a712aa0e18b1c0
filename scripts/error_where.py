"""Where a weights file's error lies on the real evaluation pairs: EPE, bad-1 and bias over the pixels with
ground truth, split by occlusion, nearness to a depth edge, image texture, disparity and distance to a depth
jump, beside OpenCV's SGBM.

    python scripts/error_where.py [--weights W] [--sets motorcycle cones] [--iters 6 6]
    python scripts/error_where.py --sets synthetic scenes photos --pairs 6 --size 384 512    # validation pairs, pooled
    python scripts/error_where.py --resolution      # bad-1 by distance to a jump: the output, its 1/4 field, the truth's

An analysis for the closing notes of the real-photograph work, never a way to choose weights or settings (the
real pairs are evaluation data only). The splits come from the ground truth and the left image alone:

* occluded: the pixel's match lies behind a nearer surface in the right view (the left disparity map forward
  warped to the right view keeps the largest disparity at each column; a pixel is occluded when that is more
  than 1 px larger than its own);
* edge: within 3 px of a jump of more than 2 px between neighbouring ground-truth disparities (not occluded);
* texture: the standard deviation of the grey left image in a 7x7 window, in three bands (flat < 4, some
  4-12, strong >= 12, on 0-255), over the pixels that are neither occluded nor at an edge;
* disparity: the pair's ground-truth disparity in four bands of equal pixel count (quartiles);
* distance to a jump: the distance (px) from a visible pixel to the nearest jump of more than 2 px between
  neighbouring ground-truth disparities, in bands (a matcher that bleeds disparity across depth edges loses
  precision over tens of pixels from them, not only beside them).

Each row: the share of the pair's valid pixels in the split, then EPE / bad-1 / mean signed error (prediction -
truth) / median absolute error for mipnet and SGBM (64 disparities, block 5, holes counted as disparity 0, as
`mipnet eval` does; for generated sets the smallest multiple of 16 above their largest disparity), and the share of
all of mipnet's bad-1 pixels that fall in the split. Generated sets (``synthetic``, ``scenes``, ``photos``: the
validation pairs from seed 2,000,000, as `scripts/validate_weights.py`) pool the pixels of ``--pairs`` pairs per
split.

``--resolution`` asks instead whether the error at depth jumps is set by the 1/4 resolution the network matches at.
Per band of distance to a jump it prints bad-1 of: the field the 1/16 level hands to the 1/4 level (at full
resolution, as `iters=(n16, 0)` outputs it); the network's output (its 1/4 field upsampled by the learned
convex weights); that 1/4 field (the state's ``flow4``) upsampled bilinearly; and two fields made from the ground truth
at the same 1/4 resolution (the median of each 4x4 block's valid truth), upsampled by nearest neighbour and
bilinearly. The truth's rows bound what a perfect 1/4 field gives without learned upsampling; where the network's own
field falls far short of them, its error lies in the matching at 1/4, not in the resolution.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import ndimage

import mipnet
from mipnet.data import PhotoStereo, SceneStereo, SyntheticStereo
from mipnet.data.real import REAL_SETS, RealPairs
from mipnet.data.synthetic import VALIDATION_SEED_START
from mipnet.model.losses import near_jump
from mipnet.model.network import _padding as network_padding
from mipnet.stereo.baselines import sgbm

TEXTURE_BANDS = ((0.0, 4.0, "flat"), (4.0, 12.0, "some"), (12.0, np.inf, "strong"))
JUMP_DISTANCE_BANDS = (0, 3, 6, 12, 24, 48, np.inf)


def occluded(disparity: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Left pixels hidden in the right view by a nearer surface, from the left ground truth alone."""
    height, width = disparity.shape
    right_view = np.zeros((height, width), np.float32)
    rows, cols = np.nonzero(valid)
    # a left pixel (y, x) with disparity d lands on right column x - d
    target = np.rint(cols - disparity[rows, cols]).astype(np.int64)
    inside = (target >= 0) & (target < width)
    np.maximum.at(right_view, (rows[inside], target[inside]), disparity[rows[inside], cols[inside]])
    seen = np.zeros_like(valid)
    seen[rows[inside], cols[inside]] = right_view[rows[inside], target[inside]] <= disparity[rows[inside], cols[inside]] + 1
    return valid & ~seen


def near_edge(disparity: np.ndarray, valid: np.ndarray, jump: float = 2.0, radius: int = 3) -> np.ndarray:
    """Pixels within ``radius`` px of a jump of more than ``jump`` px between neighbouring valid truths."""
    # the jump pixels themselves (the training loss's rule, at radius 0), then grown by a diamond of `radius` steps
    edge = near_jump(disparity, valid, radius=0, jump=jump)
    return ndimage.binary_dilation(edge, iterations=radius) & valid


def local_std(left: np.ndarray, size: int = 7) -> np.ndarray:
    """Standard deviation of the grey image in a ``size`` x ``size`` window (0-255)."""
    grey = left.astype(np.float64).mean(axis=2)
    mean = ndimage.uniform_filter(grey, size)
    return np.sqrt(np.maximum(ndimage.uniform_filter(grey * grey, size) - mean * mean, 0.0))


def scores(signed: np.ndarray) -> tuple[float, float, float, float]:
    """EPE, bad-1 (%), mean signed error and median absolute error of the signed errors ``signed``."""
    error = np.abs(signed)
    return float(error.mean()), float((error > 1).mean() * 100), float(signed.mean()), float(np.median(error))


def splits(pair: dict) -> list[tuple[str, np.ndarray]]:
    truth, valid = pair["disparity"], pair["valid"]
    occ = occluded(truth, valid)
    edge = near_edge(truth, valid) & ~occ
    rest = valid & ~occ & ~edge
    texture = local_std(pair["left"])
    rows = [("all", valid), ("occluded", occ), ("edge (visible)", edge), ("elsewhere", rest)]
    rows += [(f"  texture {name} [{lo:g}, {hi:g})", rest & (texture >= lo) & (texture < hi))
             for lo, hi, name in TEXTURE_BANDS]
    # disparity quartiles of this pair (pooled over pairs, the bands are each pair's own)
    edges = np.quantile(truth[valid], [0, 0.25, 0.5, 0.75, 1.0])
    for q, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        rows.append((f"disparity quartile {q + 1}", valid & (truth >= lo) & (truth <= hi)))
    distance = ndimage.distance_transform_edt(~near_edge(truth, valid, radius=1))
    for lo, hi in zip(JUMP_DISTANCE_BANDS[:-1], JUMP_DISTANCE_BANDS[1:]):
        rows.append((f"from a jump [{lo:g}, {hi:g}) px", valid & ~occ & (distance >= lo) & (distance < hi)))
    return rows


def pairs_of(name: str, count: int, size: tuple[int, int]) -> list[dict]:
    """The real pair ``name``, or ``count`` validation pairs of the generated set ``name`` at ``size``."""
    if name in REAL_SETS:
        return [RealPairs(name)[0]]
    maker = {"synthetic": SyntheticStereo, "scenes": SceneStereo, "photos": PhotoStereo}[name]
    return list(maker(count, *size, seed=VALIDATION_SEED_START))


def quarter_truth(truth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The truth at 1/4 resolution in 1/4-pixel units: the median of each 4x4 block's valid disparities (a block
    with none takes the nearest block's value)."""
    height, width = truth.shape
    blocks = np.full((-(-height // 4) * 4, -(-width // 4) * 4), np.nan)
    blocks[:height, :width] = np.where(valid, truth, np.nan)
    # block (i, j) holds pixels 4i..4i+3 x 4j..4j+3
    blocks = blocks.reshape(blocks.shape[0] // 4, 4, blocks.shape[1] // 4, 4).transpose(0, 2, 1, 3).reshape(
        blocks.shape[0] // 4, blocks.shape[1] // 4, 16)
    empty = np.isnan(blocks).all(axis=2)
    field = np.zeros(empty.shape)
    field[~empty] = np.nanmedian(blocks[~empty], axis=1) / 4
    if empty.any():
        nearest = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        field = field[tuple(nearest)]
    return field


def upsample(field: np.ndarray, shape: tuple[int, int], order: int, offset: tuple[int, int] = (0, 0)) -> np.ndarray:
    """A 1/4-resolution disparity field (1/4-pixel units) whose block (i, j) covers full-resolution pixels 4i..4i+3 x
    4j..4j+3 of an image padded by ``offset`` (top, left), at full resolution in pixels over ``shape``: nearest block
    (order 0), or bilinear (order 1) between block centres 4j + 1.5."""
    ys, xs = np.arange(shape[0]) + offset[0], np.arange(shape[1]) + offset[1]
    if order == 0:
        return 4 * field[(ys // 4)[:, None], (xs // 4)[None, :]]
    grid = np.meshgrid((ys - 1.5) / 4, (xs - 1.5) / 4, indexing="ij")
    return 4 * ndimage.map_coordinates(field, grid, order=1, mode="nearest")


def resolution_table(model, name: str, pairs: list[dict], iters: tuple[int, int]) -> None:
    """bad-1 (%) by distance to a jump of the output, its 1/4 field and the truth's 1/4 fields (see --resolution)."""
    columns = ("1/16 hand-over", "output (convex)", "its 1/4 field, bilinear", "truth at 1/4, nearest",
               "truth at 1/4, bilinear")
    pooled: dict[str, list[list[np.ndarray]]] = {}
    for pair in pairs:
        truth, valid = pair["disparity"], pair["valid"]
        height, width = truth.shape
        pred, state = model.forward_with_state(pair["left"], pair["right"], iters=iters)
        # the state's fields cover the image padded as the network pads it (flow4's x component is -disparity)
        left, _, top, _ = network_padding(height, width)
        # (n16, 0) iterations stop at 1/16 and output the field handed to the 1/4 level, upsampled
        handover = model(pair["left"], pair["right"], iters=(iters[0], 0))
        fields = [handover, pred, upsample(-state.flow4[0, 0], (height, width), 1, (top, left))]
        quarter = quarter_truth(truth, valid)
        fields += [upsample(quarter, (height, width), 0), upsample(quarter, (height, width), 1)]
        occ = occluded(truth, valid)
        distance = ndimage.distance_transform_edt(~near_edge(truth, valid, radius=1))
        bands = [("all visible", valid & ~occ)]
        bands += [(f"from a jump [{lo:g}, {hi:g}) px", valid & ~occ & (distance >= lo) & (distance < hi))
                  for lo, hi in zip(JUMP_DISTANCE_BANDS[:-1], JUMP_DISTANCE_BANDS[1:])]
        for label, mask in bands:
            rows = pooled.setdefault(label, [[] for _ in columns])
            for k, field in enumerate(fields):
                rows[k].append(np.abs(field[mask] - truth[mask]) > 1)
    print(f"\n{name}: bad-1 (%) by distance to a jump, iterations {iters}")
    print(f"{'band':<28} {'share':>6}  " + "  ".join(f"{c:>23}" for c in columns))
    total = sum(a.size for a in pooled["all visible"][0])
    for label, rows in pooled.items():
        bad = [np.concatenate(r) for r in rows]
        if bad[0].size:
            print(f"{label:<28} {bad[0].size / total * 100:5.1f}%  " + "  ".join(f"{b.mean() * 100:22.1f}%" for b in bad))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--weights", default=None, help="weights file (default: the shipped ones)")
    parser.add_argument("--sets", nargs="+", default=["motorcycle", "cones"],
                        choices=[*REAL_SETS, "synthetic", "scenes", "photos"])
    parser.add_argument("--pairs", type=int, default=6, help="pairs of a generated set")
    parser.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"),
                        help="size of a generated set's pairs")
    parser.add_argument("--iters", type=int, nargs=2, default=(6, 6))
    parser.add_argument("--resolution", action="store_true",
                        help="bad-1 by distance to a jump of the output, its 1/4 field and the truth at 1/4")
    args = parser.parse_args()
    model = (mipnet.load(args.weights) if args.weights else mipnet.MIPNet.pretrained()).eval()
    for name in args.sets:
        if args.resolution:
            resolution_table(model, name, pairs_of(name, args.pairs, tuple(args.size)), tuple(args.iters))
            continue
        pooled: dict[str, list] = {}
        valid_pixels = 0
        for pair in pairs_of(name, args.pairs, tuple(args.size)):
            truth, valid = pair["disparity"], pair["valid"]
            span = 64 if name in REAL_SETS else 16 * (int(truth[valid].max()) // 16 + 1)
            pred = model(pair["left"], pair["right"], iters=tuple(args.iters))
            classic = sgbm(pair["left"], pair["right"], num_disparities=span)[0]
            valid_pixels += int(valid.sum())
            for label, mask in splits(pair):
                rows = pooled.setdefault(label, [[], []])
                rows[0].append(pred[mask] - truth[mask])
                rows[1].append(classic[mask] - truth[mask])
        bad = sum(int((np.abs(e) > 1).sum()) for e in pooled["all"][0])
        what = "1 pair" if name in REAL_SETS else f"{args.pairs} validation pairs at {args.size[0]}x{args.size[1]}"
        print(f"\n{name}: {what}, {valid_pixels} pixels with ground truth, iterations {tuple(args.iters)}")
        print(f"{'split':<30} {'share':>6}  {'mipnet EPE / bad-1 / bias / median':>37}  "
              f"{'SGBM EPE / bad-1 / bias / median':>35}  {'of bad-1':>8}")
        for label, (mine, theirs) in pooled.items():
            mine, theirs = np.concatenate(mine), np.concatenate(theirs)
            if mine.size == 0:
                continue
            m, s = scores(mine), scores(theirs)
            print(f"{label:<30} {mine.size / valid_pixels * 100:5.1f}%  {m[0]:7.2f} {m[1]:8.1f}% {m[2]:+8.2f} {m[3]:8.2f}  "
                  f"{s[0]:7.2f} {s[1]:8.1f}% {s[2]:+7.2f} {s[3]:8.2f}  {(np.abs(mine) > 1).sum() / bad * 100:7.1f}%")


if __name__ == "__main__":
    main()
