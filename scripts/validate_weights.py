"""The validation table of a weights file beside the untrained network and OpenCV SGBM, on the held-out
sets of training validation (pair seeds from 2,000,000, `VALIDATION_SEED_START`) plus the real Middlebury
Motorcycle pair and, once fetched (`mipnet fetch cones`), the real Middlebury Cones pair (evaluation only).

    python scripts/validate_weights.py RUN/model.safetensors --out table.json [--size 256 320] [--pairs 8] [--no-untrained]

The JSON (``{"trained": ..., "untrained": ..., "sgbm": ..., "setup": ...}``) is what ``scripts/ship_weights.py
--validation`` records in the shipped file (``setup``: pairs per set, size, iterations, first pair seed).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import mipnet
from mipnet.data.synthetic import VALIDATION_SEED_START
from mipnet.training.validation import format_validation, validate_model, validate_sgbm, validation_sets


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights")
    p.add_argument("--out", required=True, help="JSON file for the tables")
    p.add_argument("--size", type=int, nargs=2, default=(256, 320), metavar=("H", "W"))
    p.add_argument("--pairs", type=int, default=8)
    p.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    p.add_argument("--no-untrained", dest="untrained", action="store_false",
                   help="skip the untrained network's table (it only shows where training started)")
    args = p.parse_args()
    sets = validation_sets(tuple(args.size), args.pairs)
    sets["motorcycle"] = [mipnet.data.RealPairs("motorcycle")[0]]
    try:
        sets["cones"] = [mipnet.data.RealPairs("cones")[0]]
    except mipnet.errors.ArgumentError as error:  # not fetched: the table goes without it
        print(f"validate_weights: no cones row ({error})", file=sys.stderr)
    mipnet.manual_seed(0)
    models = {"trained": mipnet.load(args.weights).eval()}
    if args.untrained:
        models["untrained"] = mipnet.MIPNet().eval()
    tables = {}
    for name, model in models.items():
        start = time.perf_counter()
        tables[name] = validate_model(lambda l, r: model(l, r, iters=tuple(args.iters)), sets)
        print(f"{name} ({time.perf_counter() - start:.0f} s)\n" + format_validation(None, tables[name]))
    tables["sgbm"] = validate_sgbm(sets)
    print("sgbm\n" + format_validation(None, tables["sgbm"]))
    tables["setup"] = {"pairs": args.pairs, "size": list(args.size), "iters": list(args.iters),
                       "seeds_from": VALIDATION_SEED_START}
    with open(args.out, "w") as f:
        json.dump(tables, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
