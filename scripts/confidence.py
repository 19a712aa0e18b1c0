"""How well `mipnet.match_confidence` tells where a weights file's disparity is backed by the images.

    python scripts/confidence.py WEIGHTS [--pairs 8] [--size 384 512] [--thresholds 0.3 0.5 0.7] [--real]
    python scripts/confidence.py WEIGHTS --pairs 0 --figure docs/confidence_open_water.png

On validation pairs (`make_pair`, seeds from 2,000,000 as `scripts/validate_weights.py`), in air and in the
`turbid` and `low_light` water of the validation sets, it prints for each threshold C the share of valid pixels
whose confidence is >= C (kept) and the EPE / bad-3 of the kept and of the dropped pixels. Under water it also
renders each pair with its far half (the pixels below the pair's median disparity) beyond the water's reach:
rendered at disparity 0, i.e. at the water model's `z_max`, those pixels show pure veil, as open water does, and
the line gives the share of them kept and the network's median disparity there (the truth is about 1.7 px).
``--real`` adds the real Middlebury pairs (Motorcycle; Cones once fetched), for evaluation only. ``--figure`` draws
the first validation pair in turbid water, as rendered and with its far half as open water: left image, disparity,
confidence, and the disparity where the confidence reaches the middle threshold.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import mipnet
from mipnet.stereo.metrics import evaluate
from mipnet.data.synthetic import VALIDATION_SEED_START, apply_water, make_pair, water_for_item
from mipnet.stereo.filters import box_sum
from mipnet.underwater import degrade


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights")
    p.add_argument("--pairs", type=int, default=8)
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    p.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    p.add_argument("--thresholds", type=float, nargs="+", default=[0.3, 0.5, 0.7])
    p.add_argument("--real", action="store_true", help="also the real Middlebury pairs (evaluation only)")
    p.add_argument("--figure", help="PNG of the first turbid validation pair, plain and with open water")
    args = p.parse_args()
    model = mipnet.load(args.weights).eval()
    iters = tuple(args.iters)
    print(f"{args.pairs} validation pairs per set from seed {VALIDATION_SEED_START:,} at {args.size[0]}x{args.size[1]}, "
          f"iterations {iters}; mipnet.match_confidence with its defaults (window 15, band 1-8 px)")
    for name in ("air", "turbid", "low_light") if args.pairs > 0 else ():
        predictions, truths, confidences, veil, veil_disparity, near_objects = [], [], [], [], [], []
        for seed in range(VALIDATION_SEED_START, VALIDATION_SEED_START + args.pairs):
            pair = make_pair(*args.size, seed)
            valid = pair["valid"]
            if name != "air":
                options, _ = water_for_item(name, seed)
                far = far_half(pair)
                left, right = degrade(pair["left"], pair["right"], np.where(far, 0.0, pair["disparity"]), seed=1, **options)
                d = model(left, right, iters=iters)
                veil.append(mipnet.match_confidence(left, right, d)[far])
                # within 16 px (Chebyshev) of a pixel that is not open water: the 33x33 box around it holds one
                near_objects.append(box_sum((~far).astype(np.float32), 33)[far] > 0.5)
                veil_disparity.append(d[far])
                apply_water(pair, name, seed)
            d = model(pair["left"], pair["right"], iters=iters)
            predictions.append(d[valid])
            truths.append(pair["disparity"][valid])
            confidences.append(mipnet.match_confidence(pair["left"], pair["right"], d)[valid])
        report(name, np.concatenate(predictions), np.concatenate(truths), np.concatenate(confidences), args.thresholds,
               veil)
        if veil:
            near, c = np.concatenate(near_objects), np.concatenate(veil)
            kept = c >= args.thresholds[len(args.thresholds) // 2]
            print(f"  open water: median disparity {np.median(np.concatenate(veil_disparity)):.1f} px (truth ~1.7); "
                  f"{100 * near.mean():.0f}% of it lies within 16 px of the objects, {100 * near[kept].mean():.0f}% of what "
                  f"C {args.thresholds[len(args.thresholds) // 2]:g} keeps")
    if args.figure:
        figure(model, args.size, iters, args.thresholds[len(args.thresholds) // 2], args.figure)
    for name in ("motorcycle", "cones") if args.real else ():
        try:
            pair = mipnet.data.RealPairs(name)[0]
        except mipnet.errors.ArgumentError as error:  # cones not fetched
            print(f"{name}: skipped ({error})")
            continue
        d = model(pair["left"], pair["right"], iters=iters)
        valid = pair["valid"]
        report(name, d[valid], pair["disparity"][valid],
               mipnet.match_confidence(pair["left"], pair["right"], d)[valid], args.thresholds, [])
    return 0


def report(name: str, pred: np.ndarray, gt: np.ndarray, c: np.ndarray, thresholds: list[float],
           veil: list[np.ndarray]) -> None:
    """A set's line and one line per threshold: kept share, EPE / bad-3 of the kept and of the dropped pixels
    (``pred``, ``gt``, ``c``: the valid pixels of every pair, flattened)."""
    print(f"{name}: all {score(pred, gt)}")
    for t in thresholds:
        kept = c >= t
        line = f"  C {t:g}: kept {100 * kept.mean():5.1f}%  {score(pred[kept], gt[kept])}  |  dropped {score(pred[~kept], gt[~kept])}"
        if veil:
            line += f"  |  open water kept {100 * (np.concatenate(veil) >= t).mean():4.1f}%"
        print(line)


def far_half(pair: dict) -> np.ndarray:
    """The valid pixels below the pair's median disparity: the part rendered as open water."""
    valid = pair["valid"]
    return valid & (pair["disparity"] < np.median(pair["disparity"][valid]))


def figure(model, size, iters, threshold: float, path: str) -> None:
    """Rows: the pair as rendered, then with its far half as open water; panels: left, disparity, confidence,
    disparity where confidence >= threshold (black elsewhere), one colour scale."""
    from mipnet.stereo import io, viz

    seed = VALIDATION_SEED_START
    pair = make_pair(*size, seed)
    options, _ = water_for_item("turbid", seed)
    valid = pair["valid"]
    far = far_half(pair)
    lo, hi = np.percentile(pair["disparity"][valid], [1, 99])
    gap = np.full((size[0], 6, 3), 255, np.uint8)
    rows = []
    for rendered in (pair["disparity"], np.where(far, 0.0, pair["disparity"])):
        left, right = degrade(pair["left"], pair["right"], rendered, seed=1, **options)
        d = model(left, right, iters=iters)
        confidence = mipnet.match_confidence(left, right, d)
        panels = [left, viz.colorize(d, vmin=lo, vmax=hi), viz.colorize(confidence, vmin=0.0, vmax=1.0, cmap="gray"),
                  viz.colorize(d, vmin=lo, vmax=hi, valid=confidence >= threshold)]
        rows.append(np.concatenate(sum(([p, gap] for p in panels), [])[:-1], axis=1))
    io.write_image(path, np.concatenate([rows[0], np.full((6, rows[0].shape[1], 3), 255, np.uint8), rows[1]], axis=0))
    print(f"wrote {path}")


def score(pred: np.ndarray, gt: np.ndarray) -> str:
    """EPE / bad-3 of the pixels given (mipnet.stereo.metrics)."""
    if not pred.size:
        return "  (none)"
    m = evaluate(pred, gt)
    return f"{m['epe']:5.2f} px / {m['bad3']:5.1f}%"


if __name__ == "__main__":
    sys.exit(main())
