"""How the training crops' disparities compare with the evaluation pairs': the share of valid pixels below 8 and
16 px, the median and the 90th percentile, for generated training sources after augmentation (as `mipnet train`
builds them) and for the held-out pairs of the same generators at the evaluation's size.

    python scripts/disparity_distribution.py [--crop 256 512] [--size 384 512] [--samples 48]
        [--spatial-scale -0.2 0.4] [--sources synthetic-underwater scenes-underwater]

The generators' disparities grow with the drawn width and training pairs are drawn larger than the crop, so the
crop zooms in before any scale augmentation; this prints how far the training distribution sits from the
evaluation's (docs/training.md, stage 8).
"""

from __future__ import annotations

import argparse

import numpy as np

from mipnet.data import SceneStereo, SyntheticStereo
from mipnet.data.synthetic import VALIDATION_SEED_START
from mipnet.training import resolve_config
from mipnet.training.fit import build_dataset


def summary(samples) -> str:
    d = np.concatenate([s["disparity"][s["valid"] & (s["disparity"] > 0)] for s in samples])
    return (f"<8 px {100 * (d < 8).mean():5.1f}%   <16 px {100 * (d < 16).mean():5.1f}%   "
            f"median {np.median(d):6.1f}   p90 {np.percentile(d, 90):6.1f}")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--crop", type=int, nargs=2, default=(256, 512))
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), help="the evaluation pairs' size")
    p.add_argument("--samples", type=int, default=48)
    p.add_argument("--spatial-scale", type=float, nargs=2, default=(-0.2, 0.4))
    p.add_argument("--sources", nargs="+", default=["synthetic-underwater", "scenes-underwater"])
    args = p.parse_args()
    evaluation = {"synthetic": SyntheticStereo, "scenes": SceneStereo}
    for source in args.sources:
        config = resolve_config("cpu", overrides={"crop": tuple(args.crop), "data": [source],
                                                  "spatial_scale": tuple(args.spatial_scale)})
        mixture, augmentors = build_dataset(config)
        crops = [augmentors[0](mixture[i], np.random.default_rng(i)) for i in range(args.samples)]
        print(f"{source:22s} training crops {args.crop[0]}x{args.crop[1]}, scale {tuple(args.spatial_scale)}: "
              f"{summary(crops)}")
        generator = evaluation[source.split("-")[0]]
        held_out = generator(args.samples, *args.size, seed=VALIDATION_SEED_START)
        print(f"{source.split('-')[0]:22s} held-out pairs {args.size[0]}x{args.size[1]}:{' ' * 17}{summary(held_out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
