"""The video table of docs/video.md: a warm-started mipnet.Stream against cold MIPNet on generated moving-camera
sequences, and the reset after a cut; Markdown and JSON, with the machine header.

    python scripts/stream_table.py --out-md stream_table.md --out-json stream_table.json
    python scripts/stream_table.py --sequences 1 --frames 3 --size 64 96 --cut-frames 3 --cut-at 1   # a quick check

Part 1: ``--sequences`` sequences of ``--frames`` frames (``mipnet.data.make_sequence``, seeds from ``--seed``, no
cut): per frame index and over all frames, EPE, bad-3, seconds per frame and flicker of cold MIPNet at
``--cold-iters`` on every frame and of the stream (its first frame cold at ``--cold-iters``, the others warm at
``--warm-iters``), beside the ground truth's flicker. Part 2: the same seeds with a cut at ``--cut-at`` in sequences of
``--cut-frames``: the EPE of the cut frame, stream (reset) against cold. Then the issue's targets, each with the
measured ratio: stream EPE within 5 % of cold's, stream time per frame at most 0.55x cold's, stream flicker no higher
than cold's, and the cut frame's EPE within 5 % of cold's.

Timing: stop training runs and other heavy processes first (CONTRIBUTING.md, "Benchmark"); the two methods take
turns sequence by sequence in one process, after one untimed forward that warms the allocator and kernel caches.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

import mipnet
from mipnet.bench.machine import fma_peak_gflops, machine_header, peak_drift_line
from mipnet.cli.sequence_eval import score_methods, sequence_methods
from mipnet.cli.stream import DEFAULT_WARM_ITERS
from mipnet.data.sequences import make_sequence
from mipnet.model.stream import CARRY_CHOICES, DEFAULT_CARRY, DEFAULT_RESET
from mipnet.stereo.evaluation import format_table
from mipnet.stereo.temporal import comparison_rows, summarise_frames
from mipnet.utils.files import atomic_write

#: the issue's targets: EPE and cut-frame EPE within 5 % of cold's, time at most 0.55x cold's
EPE_MARGIN, TIME_SHARE = 1.05, 0.55


def _targets(summaries: dict, cut: dict, cold: str, stream: str) -> list[dict]:
    """The issue's four targets with their measured values."""
    c, s = summaries[cold]["all"], summaries[stream]["all"]
    return [
        {"target": f"stream EPE <= {EPE_MARGIN} x cold EPE", "ratio": s["epe"] / c["epe"],
         "met": s["epe"] <= EPE_MARGIN * c["epe"]},
        {"target": f"stream seconds per frame <= {TIME_SHARE} x cold", "ratio": s["seconds"] / c["seconds"],
         "met": s["seconds"] <= TIME_SHARE * c["seconds"]},
        {"target": "stream flicker <= cold flicker", "ratio": s["flicker"] / c["flicker"],
         "met": s["flicker"] <= c["flicker"]},
        {"target": f"cut frame: stream EPE <= {EPE_MARGIN} x cold EPE", "ratio": cut["stream_epe"] / cut["cold_epe"],
         "met": cut["stream_epe"] <= EPE_MARGIN * cut["cold_epe"]},
    ]


def _plain(value):
    """``value`` with NaN as None and numpy scalars as Python numbers, for strict JSON."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return None if math.isnan(value) else float(value)
    return value.item() if isinstance(value, np.generic) else value


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=10)
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    ap.add_argument("--seed", type=int, default=1_000_000, help="first sequence seed (default: the evaluation range)")
    ap.add_argument("--water", default=None, help="an underwater preset for every sequence (default: in air)")
    ap.add_argument("--cold-iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    ap.add_argument("--warm-iters", type=int, nargs=2, default=DEFAULT_WARM_ITERS, metavar=("N16", "N4"))
    ap.add_argument("--reset", type=float, default=DEFAULT_RESET, help="the stream's reset threshold")
    ap.add_argument("--carry", nargs="+", default=DEFAULT_CARRY, choices=CARRY_CHOICES,
                    help=f"the state pieces the stream carries (default {' '.join(DEFAULT_CARRY)})")
    ap.add_argument("--cut-frames", type=int, default=6, help="frames of the sequences with a cut (part 2)")
    ap.add_argument("--cut-at", type=int, default=3, help="the frame of the cut (part 2)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out-md", help="write the Markdown here too")
    ap.add_argument("--out-json", help="write the results as JSON here")
    a = ap.parse_args()
    mipnet.set_num_threads(a.threads)
    header, peak = machine_header(a.threads)
    print(header, flush=True)
    size, seeds = tuple(a.size), range(a.seed, a.seed + a.sequences)
    model = mipnet.MIPNet.pretrained()
    methods = sequence_methods(model, tuple(a.cold_iters), tuple(a.warm_iters), a.reset, carry=tuple(a.carry))
    cold, stream = list(methods)
    warm_up = make_sequence(a.seed, frames=1, size=size, water=a.water)[0]
    model(warm_up["left"], warm_up["right"], iters=tuple(a.cold_iters))

    def progress(index: int, method: str, records: list[dict]) -> None:
        epe = np.mean([r["epe"] for r in records])
        seconds = np.mean([r["seconds"] for r in records])
        print(f"  sequence {seeds[index]} {method}: epe {epe:.3f} px, {seconds:.3f} s per frame", flush=True)

    print(f"part 1: {a.sequences} sequences of {a.frames} frames at {size[0]}x{size[1]}, water {a.water}", flush=True)
    results = score_methods((make_sequence(seed, frames=a.frames, size=size, water=a.water) for seed in seeds),
                            methods, progress)
    summaries = {name: summarise_frames(records) for name, records in results.items()}
    rows, columns = comparison_rows(summaries)
    warm_frames = {name: summarise_frames([records[1:] for records in per])["all"] for name, per in results.items()}

    print(f"part 2: the same seeds, {a.cut_frames} frames with a cut at frame {a.cut_at}", flush=True)
    cut_results = score_methods((make_sequence(seed, frames=a.cut_frames, size=size, water=a.water, cut_at=a.cut_at)
                                 for seed in seeds), methods, progress)
    cut = {"cold_epe": float(np.mean([records[a.cut_at]["epe"] for records in cut_results[cold]])),
           "stream_epe": float(np.mean([records[a.cut_at]["epe"] for records in cut_results[stream]])),
           "resets": sum(not records[a.cut_at]["warm"] for records in cut_results[stream]),
           "false_resets": sum(not r["warm"] for records in cut_results[stream] for r in records
                               if r["frame"] not in (0, a.cut_at)),
           "sequences": a.sequences}
    targets = _targets(summaries, cut, cold, stream)
    drift = peak_drift_line(peak, fma_peak_gflops(a.threads))

    command = ("python scripts/stream_table.py " + " ".join(
        [f"--sequences {a.sequences}", f"--frames {a.frames}", f"--size {size[0]} {size[1]}", f"--seed {a.seed}",
         f"--cold-iters {a.cold_iters[0]} {a.cold_iters[1]}", f"--warm-iters {a.warm_iters[0]} {a.warm_iters[1]}",
         f"--reset {a.reset:g}", f"--carry {' '.join(a.carry)}", f"--cut-frames {a.cut_frames}",
         f"--cut-at {a.cut_at}", f"--threads {a.threads}"]
        + ([f"--water {a.water}"] if a.water else [])))
    lines = [f"`{command}`", "", "```", header, drift, "```", "",
             f"{a.sequences} sequences of {a.frames} frames at {size[0]}x{size[1]} ({a.water or 'in air'}), mean over "
             "sequences; epe and flicker in px, bad3 in percent, seconds per frame. Frame 0 of the stream is cold.", "",
             format_table(rows, columns), "",
             "| frames 1.. (the stream's warm frames) | epe | bad3 | seconds | flicker |", "|---|---|---|---|---|"]
    lines += [f"| {name} | {v['epe']:.3f} | {v['bad3']:.2f} | {v['seconds']:.3f} | {v['flicker']:.3f} |"
              for name, v in warm_frames.items()]
    lines += ["", f"Cut at frame {a.cut_at} ({a.cut_frames}-frame sequences): the cut frame's EPE "
              f"{cut['stream_epe']:.3f} px (stream) against {cut['cold_epe']:.3f} px (cold); the stream reset on "
              f"{cut['resets']} of {a.sequences} cuts, and on {cut['false_resets']} frames without a cut.", "",
              "| target | measured ratio | met |", "|---|---|---|"]
    lines += [f"| {t['target']} | {t['ratio']:.3f} | {'yes' if t['met'] else 'no'} |" for t in targets]
    markdown = "\n".join(lines)
    print(markdown)
    if a.out_md:
        with atomic_write(a.out_md, "w") as f:
            f.write(markdown + "\n")
    if a.out_json:
        with atomic_write(a.out_json, "w") as f:
            json.dump(_plain({"command": command, "header": header, "drift": drift, "summaries": summaries,
                              "warm_frames": warm_frames, "cut": cut, "targets": targets,
                              "records": results, "cut_records": cut_results}), f, indent=1)


if __name__ == "__main__":
    main()
