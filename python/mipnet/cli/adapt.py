"""``mipnet adapt``: a thin command line over :func:`mipnet.training.adapt` (self-supervised fine-tuning on
unlabelled rectified pairs, no ground truth).

    mipnet adapt --left 'rov/left/*.png' --right 'rov/right/*.png' --out runs/rov
    mipnet adapt --left 'L/*.png' --right 'R/*.png' --weights W.safetensors --steps 500 --anchor 0.1 --out runs/rov
    mipnet adapt --resume --out runs/rov --steps 800
"""

from __future__ import annotations

import argparse

from .common import Iters, positive_int
from .common import show_training_log

# flags that map one-to-one onto AdaptConfig fields (the rest of the settings: --no-augment)
_FIELDS = ("batch_size", "crop", "iters", "lr", "anchor", "smoothness", "gamma", "consistency", "seed",
           "checkpoint_every", "workers")


def add_parser(sub) -> argparse.ArgumentParser:
    """Registers ``adapt`` on the ``mipnet`` sub-command parsers."""
    p = sub.add_parser("adapt", help="adapt the weights to your own unlabelled stereo footage (no ground truth)",
                       description="Self-supervised fine-tuning on rectified pairs without ground truth: photometric "
                                   "reconstruction of the left view, masked by left-right consistency, plus smoothness "
                                   "and an anchor to the starting weights (docs/training.md). Resumable.")
    p.add_argument("--left", metavar="GLOB", help="left images, e.g. 'L/*.png' (quote it; sorted, paired by position)")
    p.add_argument("--right", metavar="GLOB", help="right images, e.g. 'R/*.png'")
    p.add_argument("--weights", metavar="FILE", help="weights to start from and anchor to (default: the shipped ones)")
    p.add_argument("--out", required=True, metavar="DIR", help="run folder (model.safetensors, log.jsonl, checkpoint/)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out DIR from its newest checkpoint")
    p.add_argument("--steps", type=positive_int, help="adapt until this step (default 300)")
    p.add_argument("--crop", type=int, nargs=2, metavar=("H", "W"), help="crop size, multiples of 16 (default 192 320)")
    p.add_argument("--batch-size", type=positive_int, metavar="B", help="pairs per step (default 2)")
    p.add_argument("--iters", type=int, nargs=2, metavar=("N16", "N4"), action=Iters,
                   help="IPM iterations per level while adapting (default 4 4)")
    p.add_argument("--lr", type=float, help="constant learning rate of AdamW (default 2e-5)")
    p.add_argument("--anchor", type=float, metavar="LAMBDA",
                   help="weight of the pull towards the starting weights, LAMBDA * sum (theta - theta0)^2 (default 0.01)")
    p.add_argument("--smoothness", type=float, metavar="W", help="weight of the edge-aware smoothness (default 1e-3)")
    p.add_argument("--gamma", type=float,
                   help="prediction i of n weighs gamma^(n-1-i) (default 0.8; 0: the final prediction only)")
    p.add_argument("--consistency", type=float, metavar="PX",
                   help="left-right consistency threshold of the occlusion mask in px (default 1)")
    p.add_argument("--seed", type=int, help="seed of the data order, crops and colour jitter (default 1234)")
    p.add_argument("--checkpoint-every", type=positive_int, metavar="K", help="checkpoint every K steps (default 50)")
    p.add_argument("--workers", type=int, help="data-loading worker processes (default 1)")
    p.add_argument("--no-augment", dest="augment", action="store_false", default=None,
                   help="crop only (no colour jitter)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..errors import ArgumentError
    from ..training.adapt import adapt

    settings = {f: getattr(args, f) for f in _FIELDS + ("augment",)}
    if args.resume:
        if args.left or args.right:
            raise ArgumentError("mipnet adapt --resume: --left and --right cannot change in a resumed run")
    elif not (args.left and args.right):
        raise ArgumentError("mipnet adapt: give --left GLOB and --right GLOB (or --resume)")
    with show_training_log():
        adapt(args.left, args.right, args.out, args.weights, steps=args.steps, resume=args.resume,
              progress=not args.quiet, **settings)
    return 0
