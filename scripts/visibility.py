"""Where under water a weights file can be right at all: its error by how visible the scene's texture stays.

    python scripts/visibility.py WEIGHTS [--sets turbid low_light] [--pairs 16] [--size 384 512] [--window 9]
    python scripts/visibility.py WEIGHTS --test --pairs 50      # decompose the issue's figures (never to choose)

For each generated pair (`make_pair`, the validation seeds from 2,000,000 as `scripts/validate_weights.py`;
``--test``: the test seeds of `mipnet eval`, from 1,000,000) the clean left view gives the texture's
signal-to-noise ratio after the water (`mipnet.underwater.texture_snr`, summed over a WINDOW x WINDOW window);
the network's disparity on the degraded pair is then scored by SNR band. Where the SNR is below 1 the texture
is buried in the sensor noise: no matching can find those pixels' disparity, only a guess from their
surroundings, so the band's bad-3 is the part of a set's bad-3 that better matching cannot remove.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import mipnet
from mipnet.stereo.metrics import evaluate
from mipnet.data.synthetic import EVAL_SEED_START, VALIDATION_SEED_START, apply_water, make_pair, water_for_item
from mipnet.underwater import texture_snr

EDGES = (0.0, 1.0, 3.0, 10.0, np.inf)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights")
    p.add_argument("--sets", nargs="+", default=["turbid", "low_light"], choices=["turbid", "low_light", "coastal", "clear"])
    p.add_argument("--pairs", type=int, default=16)
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    p.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    p.add_argument("--window", type=int, nargs="+", default=[9], help="window sides, one per --texture-sigma")
    p.add_argument("--texture-sigma", type=float, nargs="+", default=[3.0], help="blurs that separate texture from shading")
    p.add_argument("--test", action="store_true", help="the test seeds of `mipnet eval` (to explain its figures)")
    args = p.parse_args()
    if len(args.window) != len(args.texture_sigma):
        p.error("give one --window per --texture-sigma")
    definitions = list(zip(args.texture_sigma, args.window))
    model = mipnet.load(args.weights).eval()
    first = EVAL_SEED_START if args.test else VALIDATION_SEED_START
    print(f"{args.pairs} pairs per set from seed {first:,} at {args.size[0]}x{args.size[1]}, iterations "
          f"{tuple(args.iters)}; texture (detail below a blur of sigma px) SNR over a window; share of valid pixels, "
          "EPE, bad-3")
    for name in args.sets:
        predictions, truths, snrs = [], [], [[] for _ in definitions]
        for seed in range(first, first + args.pairs):
            pair = make_pair(*args.size, seed)
            options, _ = water_for_item(name, seed)
            snr = [texture_snr(pair["left"], pair["disparity"], window=w, texture_sigma=t, **options) for t, w in definitions]
            apply_water(pair, name, seed)
            valid = pair["valid"]
            d = model(pair["left"], pair["right"], iters=tuple(args.iters))
            predictions.append(d[valid])
            truths.append(pair["disparity"][valid])
            for kept, m in zip(snrs, snr):
                kept.append(m[valid])
        pred, gt = np.concatenate(predictions), np.concatenate(truths)
        print(f"{name:9s} all: {score(pred, gt)}")
        for (t, w), kept in zip(definitions, snrs):
            report(pred, gt, np.concatenate(kept), f"  sigma {t:g}, {w}x{w}")
    return 0


def score(pred: np.ndarray, gt: np.ndarray) -> str:
    """EPE and bad-3 of the pixels given (mipnet.stereo.metrics)."""
    m = evaluate(pred, gt)
    return f"{m['epe']:5.2f} {m['bad3']:5.1f}%"


def report(pred: np.ndarray, gt: np.ndarray, s: np.ndarray, label: str) -> None:
    """One line: EPE and bad-3 in each band of SNR ``s``, and over SNR >= 1 (the valid pixels of every pair,
    flattened)."""
    cells = []
    for lo, hi in zip(EDGES[:-1], EDGES[1:]):
        band = (s >= lo) & (s < hi)
        if band.any():
            cells.append(f"SNR {lo:g}-{hi:g}: {100 * band.mean():4.1f}% {score(pred[band], gt[band])}")
    seen = s >= 1.0
    print(f"{label}  |  " + "  |  ".join(cells) + f"  |  SNR >= 1: {score(pred[seen], gt[seen])}")


if __name__ == "__main__":
    sys.exit(main())
