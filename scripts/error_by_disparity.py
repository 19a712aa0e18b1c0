"""Where a weights file loses: EPE by ground-truth disparity band on held-out generated pairs, at full
resolution and with the pair shrunk before inference (the disparity scaled back up), in air and under water.

    python scripts/error_by_disparity.py WEIGHTS [--size 384 512] [--pairs 6] [--scale 0.667] [--iters 4 4]
    python scripts/error_by_disparity.py WEIGHTS --per-pair turbid [--pairs 12] [--iters 6 6]

Pairs: `make_pair` from the validation seeds (2,000,000 on, as `scripts/validate_weights.py`; the test seeds of
`mipnet eval` stay unseen by analyses that guide training), plain and under the `turbid` / `low_light` presets.
If the error is the same in every band and shrinking the pair helps, what fails is not the disparity range but
evidence too faint at the full resolution (docs/training.md). The bias column is the mean signed error
(prediction - truth): far below zero, the network places what it cannot see farther than it is.
``--per-pair SET`` prints one row per pair of one set instead (air, turbid or low_light): its EPE, bad-3, median
truth, and the median signed error in 8-px bands of truth that hold at least 5% of its pixels.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import mipnet
from mipnet.stereo.metrics import evaluate
from mipnet.data import SyntheticStereo
from mipnet.data.synthetic import VALIDATION_SEED_START

BANDS = ((0, 16), (16, 32), (32, 48), (48, np.inf))
SETS = {"air": None, "turbid": "turbid", "low_light": "low_light"}


def per_pair(model, args) -> None:
    """One row per pair of set ``args.per_pair``: where its error lies, and with which sign."""
    water = SETS[args.per_pair]
    print(f"{args.per_pair}, {args.pairs} pairs at {args.size[0]}x{args.size[1]}, iterations {tuple(args.iters)}; "
          "bias = median (prediction - truth) in the 8-px band of truth, share of the pair's pixels in brackets")
    for i, s in enumerate(SyntheticStereo(args.pairs, *args.size, seed=VALIDATION_SEED_START, underwater=water)):
        d = model(s["left"], s["right"], iters=tuple(args.iters))
        signed, g = (d - s["disparity"])[s["valid"]], s["disparity"][s["valid"]]
        m = evaluate(d, s["disparity"], s["valid"])
        # band b holds truth in [8b, 8b + 8)
        band = (g // 8).astype(int)
        cells = [f"{8 * b}-{8 * b + 8}: {np.median(signed[band == b]):+6.2f} ({100 * np.mean(band == b):2.0f}%)"
                 for b in np.unique(band) if np.mean(band == b) >= 0.05]
        print(f"pair {VALIDATION_SEED_START + i}  EPE {m['epe']:5.2f}  bad-3 {m['bad3']:5.1f}%  "
              f"median truth {np.median(g):5.1f}  " + "  ".join(cells))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights")
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    p.add_argument("--pairs", type=int, default=6)
    p.add_argument("--scale", type=float, default=0.667, help="the shrunk inference size, as a fraction")
    p.add_argument("--iters", type=int, nargs=2, default=(4, 4), metavar=("N16", "N4"))
    p.add_argument("--per-pair", choices=sorted(SETS), help="one row per pair of this set instead of the bands")
    args = p.parse_args()
    model = mipnet.load(args.weights).eval()
    if args.per_pair:
        per_pair(model, args)
        return 0
    print(f"{args.pairs} pairs at {args.size[0]}x{args.size[1]}, iterations {tuple(args.iters)}; "
          "EPE (px) over valid pixels, by ground-truth disparity band")
    print(f"{'set':10} {'scale':>5} {'EPE':>6} {'bias':>6} {'bad-3':>6} " + " ".join(f"{f'{lo:g}-{hi:g}':>8}" for lo, hi in BANDS))
    for water in SETS.values():
        pairs = list(SyntheticStereo(args.pairs, *args.size, seed=VALIDATION_SEED_START, underwater=water))
        for scale in (1.0, args.scale):
            predictions, truths = [], []
            for s in pairs:
                d = model(s["left"], s["right"], iters=tuple(args.iters), scale=scale)
                predictions.append(d[s["valid"]])
                truths.append(s["disparity"][s["valid"]])
            pred, g = np.concatenate(predictions), np.concatenate(truths)
            bands = [(g >= lo) & (g < hi) for lo, hi in BANDS]
            cells = " ".join(f"{evaluate(pred[b], g[b])['epe']:8.2f}" if b.any() else f"{'-':>8}" for b in bands)
            m = evaluate(pred, g)
            print(f"{water or 'air':10} {scale:5.3g} {m['epe']:6.2f} {np.mean(pred - g):6.2f} {m['bad3']:5.1f}% {cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
