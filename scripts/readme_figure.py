"""The README's picture: the bundled example pair's left image, the shipped model's disparity, OpenCV
SGBM's disparity and the ground truth, in one colour scale.

    python scripts/readme_figure.py docs/example_infer.png
"""

from __future__ import annotations

import sys

import numpy as np

import mipnet
from mipnet.stereo import io, viz
from mipnet.stereo.baselines import sgbm
from mipnet.data.example import EXAMPLE_DISPARITY, EXAMPLE_LEFT, EXAMPLE_RIGHT
from mipnet.stereo.metrics import evaluate


def main(out: str) -> int:
    left, right = io.read_image(str(EXAMPLE_LEFT)), io.read_image(str(EXAMPLE_RIGHT))
    gt = io.read_pfm(str(EXAMPLE_DISPARITY))
    valid = np.isfinite(gt) & (gt > 0)
    ours = mipnet.MIPNet.pretrained()(left, right)
    theirs, covered = sgbm(left, right)
    theirs = np.where(covered, theirs, 0)
    lo, hi = np.percentile(gt[valid], [1, 99])
    panels = [left] + [viz.colorize(d, vmin=lo, vmax=hi) for d in (ours, theirs, np.where(valid, gt, 0))]
    gap = np.full((left.shape[0], 6, 3), 255, np.uint8)
    io.write_image(out, np.concatenate(sum(([p, gap] for p in panels), [])[:-1], axis=1))
    for name, d in (("mipnet", ours), ("sgbm", theirs)):
        m = evaluate(d, gt, valid)
        print(f"{name}: EPE {m['epe']:.2f} px, bad-3 {m['bad3']:.1f}%")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "docs/example_infer.png"))
