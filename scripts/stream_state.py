"""Which state should a video frame carry over? Accuracy (no timing) of warm-started streams on generated sequences.

    python scripts/stream_state.py [--sequences 4] [--frames 8] [--size 192 256] [--out stream_state.json]

For every warm setting (iterations x the pieces of state carried, ``mipnet.Stream(carry=...)``) and a few cold ones,
runs the shipped weights over generated moving-camera sequences (``mipnet.data.make_sequence``, no cut, no reset)
and prints the mean EPE, bad-3 and flicker over the frames after the first, beside the ground truth's flicker. Then,
on the same sequences with a cut, the reset check's error ratio ``e_new / e_old`` on the frames that continue a scene
and on the cut frames, of the default stream, for choosing the threshold (``mipnet.model.stream.DEFAULT_RESET``).
docs/video.md gives the runs behind the defaults.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

import mipnet
from mipnet.data.sequences import make_sequence
from mipnet.model.stream import CARRY_CHOICES, Stream
from mipnet.stereo.temporal import score_sequence, summarise_frames
from mipnet.utils.files import atomic_write

CARRIES = (("flow16",), ("pooled16",), ("pooled16", "hidden16"), ("pooled16", "flow4"),
           ("pooled16", "flow4", "hidden4"), ("flow16", "hidden16", "flow4", "hidden4"))
WARM_ITERS = ((1, 2), (2, 2), (1, 3), (2, 4))
COLD_ITERS = ((6, 6), (2, 2), (2, 4))


def _parse_carry(text: str) -> tuple[str, ...]:
    carry = tuple(name for name in text.split("+") if name)
    if not set(carry) <= set(CARRY_CHOICES):
        raise argparse.ArgumentTypeError(f"carry {text!r}: pieces joined by '+' from {CARRY_CHOICES}")
    return carry


def _parse_iters(text: str) -> tuple[int, int]:
    n16, _, n4 = text.partition(",")
    return int(n16), int(n4)


def _scores(sequences, make_predict) -> dict:
    """Mean EPE, bad-3 and flicker over the frames after the first of every sequence (a fresh predictor each)."""
    records = [score_sequence(frames, make_predict())[1:] for frames in sequences]
    return summarise_frames(records)["all"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=4)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--size", type=int, nargs=2, default=(192, 256), metavar=("H", "W"))
    ap.add_argument("--seed", type=int, default=1_000_000, help="first sequence seed (default: the evaluation range)")
    ap.add_argument("--water", default=None, help="an underwater preset for every sequence (default: in air)")
    ap.add_argument("--carry", type=_parse_carry, nargs="*", default=CARRIES,
                    help="carry settings to compare, pieces joined by '+' (default: a fixed list)")
    ap.add_argument("--warm-iters", type=_parse_iters, nargs="*", default=WARM_ITERS, metavar="N16,N4",
                    help="warm iterations to compare (default: a fixed list)")
    ap.add_argument("--cold-iters", type=_parse_iters, nargs="*", default=COLD_ITERS, metavar="N16,N4",
                    help="cold iterations to compare (default: a fixed list)")
    ap.add_argument("--cut-at", type=int, default=None, help="frame of the cut for the reset check (default frames/2)")
    ap.add_argument("--out", help="also write the results to this JSON file")
    a = ap.parse_args()
    model = mipnet.MIPNet.pretrained()
    size = tuple(a.size)
    seeds = range(a.seed, a.seed + a.sequences)
    sequences = [make_sequence(seed, frames=a.frames, size=size, water=a.water) for seed in seeds]
    print(f"{a.sequences} sequences of {a.frames} frames at {size[0]}x{size[1]}, water {a.water}; frames 1.. scored")
    rows = []

    def report(name: str, scores: dict) -> None:
        rows.append({"setting": name, **scores})
        print(f"{name:48s} epe {scores['epe']:.3f}  bad3 {scores['bad3']:6.2f}  flicker {scores['flicker']:.3f}"
              f"  (gt {scores['flicker_gt']:.3f})", flush=True)

    for iters in a.cold_iters:
        report(f"cold {iters}", _scores(sequences, lambda: (lambda l, r, it=iters: model(l, r, iters=it))))
    for iters in a.warm_iters:
        for carry in a.carry:
            report(f"warm {iters} carry {'+'.join(carry)}",
                   _scores(sequences, lambda: Stream(model, iters, carry=carry, reset=None)))

    cut_at = a.cut_at or a.frames // 2
    continuing, cuts = [], []
    for seed in seeds:
        frames = make_sequence(seed, frames=a.frames, size=size, water=a.water, cut_at=cut_at)
        stream = Stream(model, reset=math.inf)  # the default stream, checking every frame and never resetting
        for frame in frames:
            stream(frame["left"], frame["right"])
        ratios = stream.ratios
        cuts.append(ratios[cut_at])
        continuing += [ratio for t, ratio in enumerate(ratios) if t not in (0, cut_at)]
    print(f"reset check e_new / e_old: continuing frames max {max(continuing):.3f}, "
          f"99th percentile {np.percentile(continuing, 99):.3f}, median {np.median(continuing):.3f}; "
          f"cut frames min {min(cuts):.3f}, median {np.median(cuts):.3f}")
    if a.out:
        with atomic_write(a.out, "w") as f:
            json.dump({"size": size, "frames": a.frames, "sequences": a.sequences, "water": a.water, "rows": rows,
                       "ratios": {"continuing": continuing, "cut": cuts}}, f, indent=1)


if __name__ == "__main__":
    main()
