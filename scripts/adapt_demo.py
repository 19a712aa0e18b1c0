"""The demonstration (a) of `mipnet adapt` (docs/training.md): on a generated domain the starting weights never
trained on, self-supervised adaptation on N unlabelled pairs, then EPE on N other held-out pairs of the same
domain with their ground truth, before and after.

The domain is the `photos` pairs (stereo pairs rendered from single real photographs, mipnet.data.PhotoStereo)
made from the held-out photographs only (evaluation seeds), which the shipped weights never saw. The adaptation
pairs and the measured pairs are different seeds; they may share a photograph (the held-out split has about one
photograph in five of the collection), never a pair.

    python scripts/adapt_demo.py OUT [--pairs 20] [--size 256 320] [--steps 300] [--lr 2e-5] [--weights W]
    python scripts/adapt_demo.py OUT --resume --steps 600    # continue OUT's adaptation to step 600, measure again

Writes OUT/adapt/ (the adapt run folder: `mipnet infer --weights OUT/adapt/model.safetensors`), OUT/pairs/
and OUT/result.json with the per-pair and mean EPE / bad-1 / bad-3 before and after.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import mipnet
from mipnet.data import PhotoStereo
from mipnet.data.synthetic import EVAL_SEED_START
from mipnet.stereo import metrics
from mipnet.stereo.io import write_image
from mipnet.training import adapt
from mipnet.utils.files import atomic_write

#: The measured pairs' seeds start this far after the adaptation pairs' (different pairs, same held-out split).
MEASURED_SEED_OFFSET = 100_000


def write_pairs(dataset: PhotoStereo, folder: Path) -> None:
    """The left and right images of every pair of ``dataset`` as PNGs, names sorted in pair order."""
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True, exist_ok=True)
    for i in range(len(dataset)):
        pair = dataset[i]
        write_image(folder / "left" / f"{i:04d}.png", pair["left"])
        write_image(folder / "right" / f"{i:04d}.png", pair["right"])


def measure(model: mipnet.MIPNet, dataset: PhotoStereo, iters: tuple[int, int]) -> list[dict]:
    """EPE, bad-1 and bad-3 of ``model`` on every pair of ``dataset`` (valid ground truth only)."""
    rows = []
    for i in range(len(dataset)):
        pair = dataset[i]
        scores = metrics.evaluate(model(pair["left"], pair["right"], iters=iters), pair["disparity"], pair["valid"])
        rows.append({"seed": pair["meta"]["seed"], "photo": pair["meta"]["photo"],
                     **{k: float(scores[k]) for k in ("epe", "bad1", "bad3")}})
    return rows


def summary(rows: list[dict]) -> dict:
    return {k: float(np.mean([r[k] for r in rows])) for k in ("epe", "bad1", "bad3")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--pairs", type=int, default=20)
    parser.add_argument("--size", type=int, nargs=2, default=(256, 320), metavar=("H", "W"))
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--lr", type=float, default=2e-5)
    parser.add_argument("--crop", type=int, nargs=2, default=(192, 320), metavar=("H", "W"))
    parser.add_argument("--weights", default=None, help="starting weights (default: the shipped ones)")
    parser.add_argument("--iters", type=int, nargs=2, default=(6, 6), help="iterations when measuring")
    parser.add_argument("--resume", action="store_true",
                        help="continue the adaptation in OUT/adapt to --steps (its own settings kept), measure again")
    args = parser.parse_args()
    height, width = args.size
    adapted_on = PhotoStereo(args.pairs, height, width, seed=EVAL_SEED_START)
    measured_on = PhotoStereo(args.pairs, height, width, seed=EVAL_SEED_START + MEASURED_SEED_OFFSET)
    iters = tuple(args.iters)
    run = args.out / "adapt"
    if args.resume:
        start = mipnet.load(str(run / "start.safetensors"))
    else:
        write_pairs(adapted_on, args.out / "pairs")
        start = mipnet.load(args.weights) if args.weights else mipnet.MIPNet.pretrained()
    before = measure(start.eval(), measured_on, iters)
    began = time.time()
    if args.resume:
        adapt(None, None, str(run), steps=args.steps, resume=True)
    else:
        adapt(str(args.out / "pairs" / "left" / "*.png"), str(args.out / "pairs" / "right" / "*.png"),
              str(run), weights=args.weights, steps=args.steps, lr=args.lr, crop=tuple(args.crop))
    seconds = time.time() - began
    after = measure(mipnet.load(str(args.out / "adapt" / "model.safetensors")).eval(), measured_on, iters)
    settings = json.loads((run / "config.json").read_text())
    result = {"domain": "photos, held-out photographs", "pairs": args.pairs, "size": [height, width],
              "steps": args.steps, "lr": settings["lr"], "crop": list(settings["crop"]), "iters": list(iters),
              "adapt_seconds": seconds, "before": summary(before), "after": summary(after),
              "gain_epe": 1.0 - summary(after)["epe"] / summary(before)["epe"],
              "per_pair": [{"before": b, "after": a} for b, a in zip(before, after)]}
    with atomic_write(args.out / "result.json", "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({k: result[k] for k in ("before", "after", "gain_epe", "adapt_seconds")}, indent=1))


if __name__ == "__main__":
    main()
