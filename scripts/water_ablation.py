"""What costs a weights file its accuracy under water: the same held-out pairs rendered with parts of the water
model switched off, and with the inputs denoised before inference.

    python scripts/water_ablation.py WEIGHTS [--pairs 12] [--size 384 512] [--iters 6 6] [--sets turbid low_light]

Pairs: `make_pair` scenes from the validation seeds (2,000,000 on, as `scripts/validate_weights.py`) under the
`turbid` and `low_light` presets. Rows: as rendered; without sensor noise (a full well of 1e8 electrons, no read
noise: the image the sensor would give with unlimited light, still quantised to 8 bits); without sensor noise or
marine snow; and the rendered pair denoised by a Gaussian blur (sigma 1 and 2 px) or OpenCV's non-local means
(h = 10) before inference. If a row without noise is far better, the network fails to match through the noise; if
denoising does not recover it, the faint texture goes with the noise (docs/training.md).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import mipnet
from mipnet.data import SyntheticStereo
from mipnet.data.synthetic import VALIDATION_SEED_START
from mipnet.stereo.metrics import MetricAccumulator

NO_NOISE = {"full_well": 1e8, "read_noise": 0.0}
RENDERINGS = {"as rendered": {}, "no sensor noise": NO_NOISE, "no sensor noise, no snow": {**NO_NOISE, "marine_snow": 0.0}}


def denoisers() -> dict:
    """Input filters applied to both views of the rendered pair: name -> function of a uint8 image."""
    import cv2

    return {
        "gaussian 1 px": lambda image: cv2.GaussianBlur(image, (0, 0), 1.0),
        "gaussian 2 px": lambda image: cv2.GaussianBlur(image, (0, 0), 2.0),
        "non-local means h=10": lambda image: cv2.fastNlMeansDenoisingColored(np.ascontiguousarray(image), None, 10, 10, 7, 21),
    }


def pooled_errors(model, pairs, iters, prepare=lambda image: image) -> tuple[float, float]:
    """EPE and bad-3 (%) pooled over the valid pixels of ``pairs``, both views passed through ``prepare``."""
    pooled = MetricAccumulator(quantiles=False)
    for s in pairs:
        pooled.update(model(prepare(s["left"]), prepare(s["right"]), iters=iters), s["disparity"], s["valid"])
    result = pooled.compute()
    return result["epe"], result["bad3"]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights")
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    p.add_argument("--pairs", type=int, default=12)
    p.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    p.add_argument("--sets", nargs="+", default=["turbid", "low_light"], choices=["turbid", "low_light"])
    args = p.parse_args()
    model = mipnet.load(args.weights).eval()
    iters = tuple(args.iters)
    print(f"{args.pairs} pairs per set at {args.size[0]}x{args.size[1]}, iterations {iters}; EPE px / bad-3 pooled")
    for preset in args.sets:
        renderings = {name: list(SyntheticStereo(args.pairs, *args.size, seed=VALIDATION_SEED_START,
                                                 underwater={"preset": preset, **overrides}))
                      for name, overrides in RENDERINGS.items()}
        for name, pairs in renderings.items():
            epe, bad3 = pooled_errors(model, pairs, iters)
            print(f"{preset:10} {name:32} {epe:6.2f} {bad3:6.1f}%", flush=True)
        # the denoisers see the pairs as rendered, not rendered again
        rendered = renderings["as rendered"]
        for name, denoise in denoisers().items():
            epe, bad3 = pooled_errors(model, rendered, iters, denoise)
            print(f"{preset:10} {'denoised: ' + name:32} {epe:6.2f} {bad3:6.1f}%", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
