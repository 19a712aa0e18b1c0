"""The speed/accuracy dial of a weights file: EPE and bad-3 on the held-out generated sets at each
iteration count, beside the seconds per pair, and SGBM once.

    python scripts/iteration_dial.py WEIGHTS [--size 384 512] [--pairs 16] [--iters 2,2 4,4 6,6 8,8] [--out dial.json]

The sets are those of training validation (``mipnet.training.validation.validation_sets``: pair seeds from
2,000,000, never trained on; the test pairs of ``mipnet eval`` start at 1,000,000); EPE and bad-x are pooled
over the valid pixels of all pairs of a set.
Seconds per pair: the wall time of the model's forward passes over the set (2 threads unless
``MIPNET_NUM_THREADS`` says otherwise) divided by the pairs.
"""

from __future__ import annotations

import argparse
import json
import time

import mipnet
from mipnet.bench.machine import cpu_name, fma_peak_gflops, machine_header, peak_drift_line
from mipnet.training.validation import validate_model, validate_sgbm, validation_sets


def cells(row: dict) -> str:
    """'air epe 4.85 bad3 46.6  turbid ...' for the sets of one table row."""
    return "  ".join(f"{k} epe {v['epe']:.2f} bad3 {v['bad3']:.1f}" for k, v in row.items() if isinstance(v, dict))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("weights")
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    p.add_argument("--pairs", type=int, default=16)
    p.add_argument("--iters", nargs="+", default=["2,2", "4,4", "6,6", "8,8"], help="N16,N4 per setting")
    p.add_argument("--sets", nargs="+", default=["air", "turbid", "low_light"])
    p.add_argument("--out", help="write the table as JSON here")
    args = p.parse_args()
    header, peak = machine_header(mipnet.get_num_threads())
    print(header, flush=True)
    model = mipnet.load(args.weights).eval()
    sets = {k: v for k, v in validation_sets(tuple(args.size), args.pairs).items() if k in args.sets}
    table: dict = {"size": list(args.size), "pairs": args.pairs, "cpu": cpu_name(), "fma_peak_gflops": peak,
                   "threads": mipnet.get_num_threads(), "sgbm": validate_sgbm(sets), "mipnet": {}}
    for spec in args.iters:
        iters = tuple(int(v) for v in spec.split(","))
        seconds = []

        def predict(left, right):
            t0 = time.perf_counter()
            out = model(left, right, iters=iters)
            seconds.append(time.perf_counter() - t0)
            return out

        with mipnet.no_grad():
            row = validate_model(predict, sets)
        row["seconds_per_pair"] = sum(seconds) / len(seconds)
        table["mipnet"][spec] = row
        print(f"iters {spec}: {cells(row)}  {row['seconds_per_pair']:.2f} s/pair", flush=True)
    if table["sgbm"]:
        print("sgbm: " + cells(table["sgbm"]))
    print(peak_drift_line(peak, fma_peak_gflops(mipnet.get_num_threads())))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(table, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
