"""``mipnet eval``: metrics of MIPNet and OpenCV's SGBM on a dataset of the registry.

    mipnet eval --dataset synthetic-underwater --preset turbid --n 50 --size 384 512
    mipnet eval --dataset survey-underwater --preset turbid --n 50 --size 384 512   # the scene within visibility
    mipnet eval --dataset kitti2015 --root /data/kitti --out kitti.jsonl     # rows written as pairs are scored
    mipnet eval --dataset motorcycle --methods mipnet                       # without OpenCV
    mipnet eval --dataset sequence --n 10 --frames 16                       # video: cold vs warm start, flicker

Before any work the command checks what it will need: OpenCV for ``--methods sgbm`` (the default
runs it), scikit-image for ``motorcycle`` and the ``photos`` sets, tifffile for ``cones``; a missing
one is one line saying what to install (exit status 2); ``--methods mipnet`` runs without OpenCV. A
dataset of one pair (the real pairs) is read before the model loads, so that its error is the
command's. A pair that cannot be read is reported once and left out of every method's pass.

On an under-water generated set (``*-underwater``) every row is followed by the same metrics over the pixels whose
texture SNR (:func:`mipnet.underwater.texture_snr` of the clean left view under the pair's water, 9x9 window) is
>= 1 and < 1, with ``share``, the percentage of the valid pixels in each: where the water left no texture above the
sensor noise, no matcher can find the disparity.

``--out FILE`` appends JSON lines as the run goes: one per pair and table row (``"method"``,
``"pair"``: the left file or the dataset index, the metrics, ``"coverage"``), written and flushed as
soon as the pair is scored, then one per table row (``"summary"``: the aggregation, ``"images"``);
every line has ``"dataset"``. A run that stops or fails keeps what it scored.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

from ..amp import autocast
from ..data.registry import DATASETS
from ..errors import ArgumentError
from .common import (USER_ERRORS, Failures, ImageSize, add_iters, add_precision, load_model, positive_float,
                     positive_int, progress_bar, require_module, unit_fraction)
from .sequence_eval import add_sequence_arguments, run_sequence_eval

METHODS = ("mipnet", "sgbm")
#: optional modules a registered dataset needs: (module, pip package)
DATASET_NEEDS = {"motorcycle": (("skimage", "scikit-image"),), "cones": (("tifffile", "tifffile"),),
                 "photos": (("skimage", "scikit-image"),), "photos-underwater": (("skimage", "scikit-image"),)}


def add_parser(sub) -> argparse.ArgumentParser:
    """Registers ``eval`` on the ``mipnet`` sub-command parsers."""
    p = sub.add_parser("eval", help="metrics of MIPNet and OpenCV SGBM on a dataset",
                       description="EPE, bad-x, D1 and more of MIPNet and OpenCV's SGBM on a registered dataset. "
                                   "SGBM needs OpenCV (pip install opencv-python-headless); --methods mipnet "
                                   "runs without it.")
    p.add_argument("--dataset", required=True, choices=list(DATASETS), help="the dataset (mipnet.data.registry)")
    p.add_argument("--root", metavar="DIR",
                   help="dataset root folder (official layout); for cones, where `mipnet fetch` put it")
    p.add_argument("--weights", metavar="FILE", help="weights file (.safetensors written by MIPNet.save; "
                                                     "default: the shipped weights)")
    add_iters(p)
    add_precision(p)
    p.add_argument("--scale", type=positive_float, default=1.0, help="MIPNet's input resize factor (as infer)")
    p.add_argument("--methods", default="mipnet,sgbm",
                   help="comma-separated: mipnet, sgbm (default both; sgbm needs OpenCV)")
    p.add_argument("--min-confidence", type=unit_fraction, default=None, metavar="C",
                   help="add a row scoring MIPNet only where its match confidence is >= C (as infer), beside "
                        "SGBM's covered row")
    p.add_argument("--preset", choices=("clear", "coastal", "turbid", "low_light", "random"),
                   help="underwater preset (random: water drawn around the presets per pair)")
    p.add_argument("--n", type=positive_int, default=50, help="number of generated pairs (synthetic sets)")
    p.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"), action=ImageSize,
                   help="generated pair size (default 384 512)")
    p.add_argument("--seed", type=int, default=1_000_000,
                   help="pair seed of the first generated pair (default 1000000: held out from training)")
    p.add_argument("--resolution", default="H", choices=("F", "H", "Q"), help="MiddEval3 resolution (default H)")
    p.add_argument("--max-pairs", type=positive_int, default=None, metavar="N", help="evaluate only the first N pairs")
    p.add_argument("--aggregation", default="mean", choices=("mean", "pooled"),
                   help="mean of per-image metrics (ETH3D) or pooled over all pixels (KITTI)")
    p.add_argument("--out", metavar="FILE",
                   help="append the results to this JSON-lines file as they come: a line per pair and row as soon "
                        "as the pair is scored, then the table's rows")
    add_sequence_arguments(p)
    p.set_defaults(func=run)
    return p


def parse_methods(text: str) -> list[str]:
    methods = [m.strip() for m in text.split(",")]
    if not methods or not set(methods) <= set(METHODS):
        raise ArgumentError(f"--methods {text!r}: expected a comma-separated list of {', '.join(METHODS)}")
    return [m for m in METHODS if m in methods]


def check_dependencies(dataset: str, methods: list[str]) -> None:
    """One line saying what to install, before any work, if an optional module the run needs is missing."""
    if "sgbm" in methods:
        others = [m for m in methods if m != "sgbm"]
        require_module("cv2", "opencv-python-headless", "--methods sgbm (OpenCV's SGBM baseline)",
                       instead=f"--methods {','.join(others)} to skip SGBM" if others else "")
    for module, package in DATASET_NEEDS.get(dataset, ()):
        require_module(module, package, f"--dataset {dataset}")


def open_dataset(args: argparse.Namespace):
    """The evaluation pairs named by ``--dataset`` (``--root`` for the on-disk sets and fetched real pairs); the
    pairs of under-water generated sets carry their texture SNR map, for the split rows."""
    from ..data.registry import open_dataset as open_registered

    entry = DATASETS[args.dataset]
    if entry.underwater and args.preset is None:
        raise ArgumentError(f"--dataset {args.dataset} needs --preset (clear, coastal, turbid, low_light, random)")
    if entry.kind == "disk" and not args.root:
        raise ArgumentError(f"--dataset {args.dataset} needs --root DIR")
    return open_registered(args.dataset, root=args.root, split="test", size=tuple(args.size), seed=args.seed,
                           count=args.n, water=args.preset, resolution=args.resolution, texture_snr=entry.underwater)


def _json_value(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no nan / inf
    if hasattr(value, "item"):  # numpy scalars
        return _json_value(value.item())
    return value


class ResultLog:
    """The ``--out`` JSON-lines file: one line per scored pair and row, then the table's rows; each line
    is flushed when written (nothing is lost when the run stops). Without a path it writes nothing."""

    def __init__(self, path: str | None, dataset: str):
        self.dataset = dataset
        self.file = open(path, "a", encoding="utf-8") if path else None

    def write(self, record: dict) -> None:
        if self.file is not None:
            self.file.write(json.dumps({"dataset": self.dataset, **{k: _json_value(v) for k, v in record.items()}})
                            + "\n")
            self.file.flush()

    def pair(self, method: str, index: int, pair: dict, output, coverage: str) -> None:
        """Scores one method's ``output`` (as a predict_fn returns it) on ``pair`` (the dataset's ``index``)
        alone, with :func:`mipnet.stereo.evaluation.evaluate_method`, and writes the line."""
        if self.file is None:
            return
        from ..stereo.evaluation import evaluate_method

        result = evaluate_method([pair], lambda left, right: output, coverage)
        metrics = {k: v for k, v in result["per_image"][0].items() if k != "name"}
        meta = pair.get("meta")
        name = meta.get("left") if isinstance(meta, dict) else None
        self.write({"method": method, "pair": str(name) if name else index,
                    **metrics, "coverage": 100.0 if coverage == "dense" else result["coverage"]})

    def close(self) -> None:
        if self.file is not None:
            self.file.close()


def run(args: argparse.Namespace) -> int:
    with autocast(enabled=args.precision == "bf16"):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from ..model import pretrained
    from ..stereo.evaluation import COVERAGES, evaluate_coverages, format_table, mipnet_rows, result_rows

    if DATASETS[args.dataset].kind == "sequence":  # stereo videos, cold against a stream: mipnet.cli.sequence_eval
        return run_sequence_eval(args, ResultLog(args.out, args.dataset + (f" ({args.preset})" if args.preset else "")))
    methods = parse_methods(args.methods)
    check_dependencies(args.dataset, methods)
    dataset = open_dataset(args)
    count = min(len(dataset), args.max_pairs) if args.max_pairs else len(dataset)
    failures = Failures("mipnet eval", args.debug)
    # a dataset of one pair is read now, before the model loads: its error is the command's (status 2)
    kept = {0: dataset[0]} if count == 1 else {}
    skipped: set[int] = set()
    current: dict = {}

    def pairs():
        """One pass per method over the pairs that can be read; a pair that cannot is reported once."""
        for i in range(count):
            if i in skipped:
                continue
            pair = kept[i] if i in kept else failures.attempt((f"pair {i}",), dataset.__getitem__, i)
            if pair is None:
                skipped.add(i)
                continue
            current["index"], current["pair"] = i, pair
            yield pair

    def on_error(name, error: Exception) -> None:
        if not isinstance(error, USER_ERRORS):
            raise error
        failures.add((str(name),), error)

    label = args.dataset + (f" ({args.preset})" if args.preset else "")
    log = ResultLog(args.out, label)
    rows = []
    try:
        if "mipnet" in methods:
            model = load_model(args.weights)
            trained = bool(args.weights) or pretrained.available()
            method = "MIPNet" + ("" if trained else " (untrained)")
            with progress_bar(count, "mipnet") as progress:
                def predict(left, right):
                    disp = model(left, right, iters=tuple(args.iters), scale=args.scale)
                    progress.update(1)
                    log.pair(method, current["index"], current["pair"], disp, "dense")
                    if args.min_confidence is not None and log.file is not None:
                        from ..stereo.confidence import match_confidence

                        confident = match_confidence(left, right, disp) >= args.min_confidence
                        log.pair(f"{method} (confidence >= {args.min_confidence:g})", current["index"],
                                 current["pair"], (disp, confident), "covered")
                    return disp

                rows += mipnet_rows(pairs(), predict, method, args.aggregation, args.min_confidence, on_error,
                                    snr_split=True)
        if "sgbm" in methods:
            from ..stereo.baselines import sgbm

            def predict_sgbm(left, right):
                output = sgbm(left, right)
                log.pair("SGBM (full coverage)", current["index"], current["pair"], output, "full")
                log.pair("SGBM (covered)", current["index"], current["pair"], output, "covered")
                return output

            # sgbm_rows' one pass, with each pair's rows written as it is scored
            results = evaluate_coverages(pairs(), predict_sgbm, COVERAGES, on_error)
            rows += (result_rows("SGBM (full coverage)", results["full"], args.aggregation, snr_split=True)
                     + result_rows("SGBM (covered)", results["covered"], args.aggregation, snr_split=True))
        for row in rows:
            log.write({**row, "summary": args.aggregation})
    finally:
        log.close()
    split = "; share: percent of the valid pixels in the row's texture-SNR band" if any("share" in r for r in rows) else ""
    print(f"{label}: {count} pairs, {args.aggregation} over images; bad-x and d1 in percent, epe/a90/rms in px{split}")
    if any(row["images"] for row in rows):
        print(format_table(rows))
    else:
        print("no pair could be scored", file=sys.stderr)
    return failures.report(count)
