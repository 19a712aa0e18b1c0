"""What a weights file does where a pale veil covers the near rows: the first pairs of the
``scenes_veiled`` validation set (left image, disparity, ground truth; brighter is nearer), and the EPE
and mean signed error (bias) in the veiled lower 40% of the rows beside the same rows without the veil.

    python scripts/veiled_figure.py WEIGHTS OUT.png [--pairs 3] [--size 384 512]

A large negative bias there means the network places pale, weakly textured near surfaces far away.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from PIL import Image

import mipnet
from mipnet.stereo.metrics import evaluate
from mipnet.training.validation import validation_sets


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights")
    p.add_argument("out")
    p.add_argument("--pairs", type=int, default=3)
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    args = p.parse_args()
    height = args.size[0]
    sets = validation_sets(tuple(args.size), args.pairs)
    model = mipnet.load(args.weights).eval()
    lower = slice(int(0.6 * height), height)  # the rows the veil covers at full strength or nearly
    rows = []
    for i in range(args.pairs):
        veiled, plain = sets["scenes_veiled"][i], sets["scenes"][i]
        truth, valid = plain["disparity"], plain["valid"]
        found = {name: model(pair["left"], pair["right"]) for name, pair in (("veiled", veiled), ("plain", plain))}
        cells = []
        for name, disparity in found.items():
            bias = float(np.mean((disparity - truth)[lower][valid[lower]]))
            cells.append(f"{name} EPE {evaluate(disparity[lower], truth[lower], valid[lower])['epe']:.2f} bias {bias:+.2f}")
        print(f"pair {i}, lower rows: " + " | ".join(cells))
        top = truth[valid].max()

        def grey(d):
            # disparity 0..max of the truth -> 0..255, as three equal channels
            return np.repeat((np.clip(d / top, 0, 1) * 255).astype(np.uint8)[..., None], 3, axis=2)

        rows.append(np.concatenate([veiled["left"], grey(found["veiled"]), grey(truth)], axis=1))
    image = Image.fromarray(np.concatenate(rows, axis=0))
    image = image.resize((image.width // 2, image.height // 2), Image.Resampling.BILINEAR).quantize(256)
    image.save(args.out, optimize=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
