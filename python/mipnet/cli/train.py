"""``mipnet train``: a thin command line over :func:`mipnet.training.fit`.

    mipnet train --preset cpu --steps 20 --out run/
    mipnet train --config run.toml --data scenes:0.7 kitti2015:/data/kitti:0.3 --out run/
    mipnet train --resume run/ --steps 2000

Settings resolve as preset < ``--config`` file < flags.
"""

from __future__ import annotations

import argparse

from .common import show_training_log
from .distributed import add_ray_arguments, trainer
from ..training.config import NOISE_SOURCES, PRESETS, RESUMABLE_OVERRIDES, load_config_file, recipe_names, resolve_config

# flags that map one-to-one onto TrainConfig fields
_FIELDS = ("steps", "schedule_steps", "batch_size", "crop", "iters", "lr", "init", "seed", "val_every", "val_pairs",
           "val_size", "val_data", "checkpoint_every", "workers", "data", "veil", "noise",
           "noise_sources", "spatial_scale", "edge_weight", "ema_decay")


def add_parser(sub) -> argparse.ArgumentParser:
    """Registers ``train`` on the ``mipnet`` sub-command parsers."""
    p = sub.add_parser("train", help="train or fine-tune MIPNet (resumable; see docs/training.md)",
                       description="Train MIPNet. Settings: preset < --config file < flags.")
    p.add_argument("--out", help="run folder (log.jsonl, model.safetensors, checkpoint/)")
    p.add_argument("--resume", metavar="DIR", help="continue the run in DIR from its newest checkpoint")
    p.add_argument("--config", metavar="FILE|RECIPE",
                   help="TOML file of TrainConfig settings, or the name of a packaged recipe "
                        f"({', '.join(recipe_names())})")
    p.add_argument("--preset", choices=sorted(PRESETS), help="named settings (paper-stage1, paper-stage2, cpu, finetune)")
    p.add_argument("--data", nargs="+", metavar="SPEC", help="NAME[:ROOT][:WEIGHT] ... (e.g. scenes:0.7 kitti2015:/data/kitti:0.3)")
    p.add_argument("--steps", type=int, help="train until this step")
    p.add_argument("--schedule-steps", type=int, help="one-cycle length (default: --steps of the first start)")
    p.add_argument("--batch-size", type=int, metavar="N", help="training pairs per step (TrainConfig default 8)")
    p.add_argument("--crop", type=int, nargs=2, metavar=("H", "W"),
                   help="size of the training crops, after augmentation (TrainConfig default 384 512)")
    p.add_argument("--iters", type=int, nargs=2, metavar=("N16", "N4"), help="IPM iterations per level while training")
    p.add_argument("--lr", type=float, help="max learning rate of the one-cycle schedule")
    p.add_argument("--init", metavar="WEIGHTS", help="start from these weights (.safetensors)")
    p.add_argument("--seed", type=int, help="seed of the initialisation, data order and augmentation (TrainConfig default 1234)")
    p.add_argument("--val-every", type=int, help="validate every K steps (0: never)")
    p.add_argument("--val-pairs", type=int, help="held-out generated pairs per validation set")
    p.add_argument("--val-size", type=int, nargs=2, metavar=("H", "W"),
                   help="size of the held-out validation pairs (TrainConfig default 256 320)")
    p.add_argument("--val-data", metavar="SPEC", help="also validate on this dataset spec")
    p.add_argument("--checkpoint-every", type=int, metavar="K",
                   help="write the resumable checkpoint every K steps (TrainConfig default 100)")
    p.add_argument("--workers", type=int, help="data-loading worker processes; with --ray: the Ray actors that share "
                                               "each step's --batch-size (default: one per node)")
    p.add_argument("--no-augment", dest="augment", action="store_false", default=None, help="crop only")
    p.add_argument("--spatial-scale", type=float, nargs=2, metavar=("LO", "HI"),
                   help="log2 range of the scale augmentation (default -0.2 0.4, RAFT-Stereo's)")
    p.add_argument("--veil", type=float, metavar="P", help="probability of the row veil augmentation (default 0)")
    p.add_argument("--noise", type=float, metavar="P",
                   help="probability of the dim-light and sensor-noise augmentation (default 0)")
    p.add_argument("--edge-weight", type=float, metavar="W",
                   help="add W times the mean error within 12 px of a ground-truth depth jump to the loss (default 0)")
    p.add_argument("--ema-decay", type=float, metavar="D",
                   help="validate and save a moving average of the weights, avg = D avg + (1 - D) weights after "
                        "every step (e.g. 0.99; default 0: the last step's weights)")
    p.add_argument("--noise-sources", choices=NOISE_SOURCES,
                   help="sources the noise reaches: all (default), or air (not the generated under-water ones)")
    p.add_argument("--freeze-bn", dest="freeze_bn", action="store_true", default=None,
                   help="keep BatchNorm statistics fixed (eval mode) while training, as RAFT-Stereo fine-tunes")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_ray_arguments(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    with show_training_log():
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from ..errors import ArgumentError

    fit = trainer(args)  # mipnet.training.fit.fit, or on Ray with --ray

    if args.resume:
        given = [f"--{f.replace('_', '-')}" for f in _FIELDS + ("augment", "freeze_bn", "config", "preset", "out")
                 if getattr(args, f, None) is not None and f != "steps" and f not in RESUMABLE_OVERRIDES]
        if given:
            raise ArgumentError(f"mipnet train --resume: {', '.join(given)} cannot change in a resumed run")
        overrides = {f: getattr(args, f) for f in RESUMABLE_OVERRIDES}
        fit(None, args.resume, resume=True, steps=args.steps, progress=not args.quiet, overrides=overrides)
        return 0
    if not args.out:
        raise ArgumentError("mipnet train: give --out DIR (a new run) or --resume DIR")
    flags = {f: getattr(args, f) for f in _FIELDS + ("augment", "freeze_bn")}
    config = load_config_file(args.config, args.preset, flags) if args.config else resolve_config(args.preset, None, flags)
    fit(config, args.out, progress=not args.quiet)
    return 0
