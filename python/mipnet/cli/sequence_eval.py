"""``mipnet eval --dataset sequence``: MIPNet cold on every frame against a warm-started :class:`mipnet.Stream`, on
generated moving-camera sequences (:func:`mipnet.data.make_sequence`).

    mipnet eval --dataset sequence --n 10 --frames 16 --size 384 512               # cold --iters vs --warm-iters
    mipnet eval --dataset sequence --n 10 --frames 6 --cut-at 3 --preset turbid    # a cut: the reset

Per frame index (the mean over the sequences) and over all frames: EPE and bad-3 over the valid pixels, the seconds
of each frame's call, and the temporal flicker of each method beside the ground truth's
(:mod:`mipnet.stereo.temporal`); the stream's resets are counted per frame. ``--out FILE`` appends a JSON line per
sequence, frame and method, then one per method's summary.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from ..data.sequences import DEFAULT_FRAMES, SequenceSet
from ..model.stream import DEFAULT_CARRY, Stream
from ..stereo.evaluation import format_table
from ..stereo.temporal import comparison_rows, score_sequence, summarise_frames
from .common import load_model, positive_int, progress_bar
from .stream import add_warm_arguments

__all__ = ["add_sequence_arguments", "sequence_methods", "score_methods", "run_sequence_eval"]


def add_sequence_arguments(parser: argparse.ArgumentParser) -> None:
    """``--frames``, ``--cut-at``, ``--warm-iters`` and ``--reset`` on ``mipnet eval``'s parser."""
    parser.add_argument("--frames", type=positive_int, default=DEFAULT_FRAMES,
                        help=f"--dataset sequence: frames per sequence (default {DEFAULT_FRAMES})")
    parser.add_argument("--cut-at", dest="cut_at", type=positive_int, default=None, metavar="T",
                        help="--dataset sequence: a different scene from frame T on (the stream's reset is measured)")
    add_warm_arguments(parser, "--dataset sequence")


def sequence_methods(model, cold_iters: tuple[int, int], warm_iters: tuple[int, int], reset: float | None,
                     scale: float = 1.0, carry: Sequence[str] = DEFAULT_CARRY) -> dict[str, Callable[[], Callable]]:
    """The two methods compared, name -> a factory of a fresh per-sequence predictor: MIPNet cold on every frame
    at ``cold_iters``, and a :class:`mipnet.Stream` (cold frames at ``cold_iters``, warm at ``warm_iters``, carrying
    ``carry``)."""
    def cold():
        return lambda left, right: model(left, right, iters=cold_iters, scale=scale)

    def stream():
        return Stream(model, warm_iters, cold_iters=cold_iters, carry=carry, reset=reset, scale=scale)

    return {f"cold {cold_iters[0]},{cold_iters[1]}": cold, f"stream {warm_iters[0]},{warm_iters[1]}": stream}


def score_methods(sequences: Iterable[list[dict]], methods: dict[str, Callable[[], Callable]],
                  on_sequence: Callable[[int, str, list[dict]], None] | None = None) -> dict[str, list[list[dict]]]:
    """Every method on every sequence (each sequence generated once): method -> the per-sequence records of
    :func:`mipnet.stereo.temporal.score_sequence`, each record with ``warm`` (the frame started from the previous
    frame's state: a stream's frame that was neither its first nor a reset). ``on_sequence(index, method,
    records)`` is called as each is scored."""
    results: dict[str, list[list[dict]]] = {name: [] for name in methods}
    for index, frames in enumerate(sequences):
        for name, make in methods.items():
            predict = make()
            records = score_sequence(frames, predict)
            resets = set(predict.resets) if isinstance(predict, Stream) else set()
            for record in records:
                record["warm"] = isinstance(predict, Stream) and record["frame"] > 0 and record["frame"] not in resets
            results[name].append(records)
            if on_sequence is not None:
                on_sequence(index, name, records)
    return results


def run_sequence_eval(args: argparse.Namespace, log) -> int:
    """``mipnet eval --dataset sequence``; ``log`` is the command's JSON-lines result log (``--out``)."""
    cut_at = args.cut_at
    dataset = SequenceSet(args.n, *args.size, seed=args.seed, frames=args.frames,
                          water=None if args.preset is None else args.preset, cut_at=cut_at)
    model = load_model(args.weights)
    methods = sequence_methods(model, tuple(args.iters), tuple(args.warm_iters), args.reset, args.scale)
    count = min(len(dataset), args.max_pairs) if args.max_pairs else len(dataset)
    seeds = [dataset.seed + i for i in range(count)]

    def sequences():
        for i in range(count):
            yield dataset[i]["frames"]

    with progress_bar(count * len(methods), "sequences", unit="sequence") as progress:
        def logged(index: int, method: str, records: list[dict]) -> None:
            for record in records:
                log.write({"method": method, "sequence": seeds[index], **record})
            progress.update(1)

        try:
            results = score_methods(sequences(), methods, logged)
            summaries = {name: summarise_frames(records) for name, records in results.items()}
            for name, summary in summaries.items():
                log.write({"method": name, "summary": "all frames", **summary["all"]})
        finally:
            log.close()
    stream_name = list(methods)[1]
    resets = [sum(1 for records in results[stream_name] if len(records) > t and not records[t]["warm"])
              for t in range(args.frames)]
    rows, columns = comparison_rows(summaries)
    for row, cold_frames in zip(rows, resets + [int(np.sum(resets[1:]))]):
        row["cold frames"] = cold_frames
    water = args.preset or "in air"
    print(f"sequence ({water}): {count} sequences of {args.frames} frames at {args.size[0]}x{args.size[1]}"
          f"{f', cut at frame {cut_at}' if cut_at else ''}; mean over sequences; epe/flicker in px, bad3 in percent, "
          f"seconds per frame; cold frames: the stream's frames that ran cold (first frame, resets; 'all': resets)")
    print(format_table(rows, columns + ["cold frames"]))
    return 0
