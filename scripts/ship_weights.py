"""Ship a campaign run's best weights inside the package, as float16 with their provenance.

    python scripts/ship_weights.py ~/.cache/mipnet/train/s1-128x256 [--weights best.safetensors] [--out FILE]
        [--validation table.json] [--init-provenance FILE] [--average EARLIER.safetensors ...]

Writes ``python/mipnet/assets/mipnet_pretrained.safetensors`` with metadata: what it was trained on
(data specs, generator version, steps, crop, batch, iterations), the exact commands
(``RUN/commands.txt``), the package version and the validation table of the step it comes from. A run
started with ``--init`` from earlier shipped weights carries their history: steps add up and their
commands come first. A run started from weights that were never shipped (a finished cycle's last weights)
names, with ``--init-provenance``, a file this script wrote for that run (``--out`` elsewhere).
``--average`` ships the mean of the run's weights and earlier weights of the same lineage, each a file this
script wrote (SWA over the ends of the campaign's one-cycle runs; validate the mean first, made by
`scripts/average_weights.py`); the metadata names the steps of every weights averaged.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from mipnet.data.synthetic import VALIDATION_SEED_START
from mipnet.model.pretrained import PRETRAINED_PATH, export_pretrained
from mipnet.serialization import average_safetensors, load_safetensors
from mipnet.training.log import TrainLog

#: The shipped file of this checkout (where an installed package's own copy comes from).
CHECKOUT_PRETRAINED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python", "mipnet", "assets",
                                   os.path.basename(PRETRAINED_PATH))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", help="run folder of mipnet train")
    p.add_argument("--weights", default="best.safetensors", help="file in the run folder (default best.safetensors)")
    p.add_argument("--validation", help="JSON of {'trained': table, 'sgbm': table} measured on these weights "
                                        "(default: the run's own validation at the weights' step)")
    p.add_argument("--out", default=CHECKOUT_PRETRAINED, help="where to write (default: the checkout's shipped file)")
    p.add_argument("--init-provenance", help="file written by this script for the weights the run started from, "
                                             "when those have no provenance of their own")
    p.add_argument("--average", nargs="+", default=[], metavar="FILE",
                   help="earlier weights of this lineage, each written by this script: ship the mean of all")
    args = p.parse_args()
    source = os.path.join(args.run, args.weights)
    _, meta = load_safetensors(source)
    step = int(meta["step"])
    config = json.loads(meta["train_config"])
    records = TrainLog(os.path.join(args.run, "log.jsonl")).records()
    validation = next((r["val"] for r in records if "val" in r and r["step"] == step), None)
    sgbm = next((r["val_sgbm"] for r in records if "val_sgbm" in r), None)
    setup = {"pairs": config["val_pairs"], "size": config["val_size"], "iters": config["val_iters"],
             "seeds_from": VALIDATION_SEED_START}
    if args.validation:
        measured = json.load(open(args.validation))
        validation, sgbm, setup = measured["trained"], measured["sgbm"], measured.get("setup", setup)
    commands_path = os.path.join(args.run, "commands.txt")
    commands = open(commands_path).read().strip().splitlines() if os.path.exists(commands_path) else []
    settings = (f"on mipnet's generated scenes ({' '.join(config['data'])}), "
                f"crop {config['crop'][0]}x{config['crop'][1]}, batch {config['batch_size']}, "
                f"iterations {tuple(config['iters'])} while training, max LR {config['lr']:g}, on a 2-core CPU")
    trained, total = f"{step} steps from scratch {settings}", step
    init = config.get("init")
    if init:
        # a run that continued shipped weights: their history first, then this run's steps
        _, init_meta = load_safetensors(args.init_provenance or init)
        if "step" not in init_meta or "trained" not in init_meta:
            raise SystemExit(f"{init}: the run started from weights without provenance (no step/trained metadata)")
        total = int(init_meta["step"]) + step
        trained = f"{total} steps: {init_meta['trained']}; then {step} more from those weights {settings}"
        commands = json.loads(init_meta.get("commands", "[]")) + commands
    extra = {}
    if args.average:
        steps = [int(load_safetensors(f)[1]["step"]) for f in args.average]
        if max(steps) >= total:
            raise SystemExit(f"--average: weights of {max(steps)} steps are not earlier than this run's {total}")
        trained = (f"the mean of the weights after {', '.join(map(str, steps))} and {total} steps of one lineage "
                   f"(SWA over the ends of one-cycle runs); the last: {trained}")
        extra["averaged_steps"] = steps + [total]
    mean = average_safetensors([source] + args.average) if args.average else None
    export_pretrained(source, args.out, tensors=mean, trained=trained, step=str(total), commands=commands,
                      validation=validation, validation_sgbm=sgbm, validation_setup=setup, **extra)
    print(f"wrote {args.out} ({os.path.getsize(args.out) / 2**20:.1f} MiB) from {source} "
          f"(step {step} of the run, {total} in all"
          f"{', averaged with ' + ' '.join(args.average) if args.average else ''})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
