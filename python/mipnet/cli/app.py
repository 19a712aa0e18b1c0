"""The ``mipnet`` command line: ``info``, ``infer``, ``eval``, ``train``. Also ``python -m mipnet``.

Errors are handled once, in :func:`main`, for every subcommand: a user error (a missing, unreadable
or corrupt file, images of different sizes, bad calibration or weights, a bad flag value, not enough
memory) prints one line ``mipnet <command>: error: <what>`` and exits with status 2; ``--debug``
(before or after the command) prints the traceback as well. A run over many pairs goes on past a
pair that fails, lists the failures at the end and exits with status 1.
"""

from __future__ import annotations

import argparse
import errno
import glob
import math
import os
import sys
import traceback
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..data.registry import DATASETS
from ..errors import ArgumentError, MipnetError, ShapeError

ASSETS = Path(__file__).resolve().parents[1] / "assets"
EXAMPLE_LEFT, EXAMPLE_RIGHT = ASSETS / "example_left.png", ASSETS / "example_right.png"
UNTRAINED_SEED = 0


def load_model(weights: str | None, quiet: bool = False):
    """The model to run: the weights file given, else the weights shipped with the package; an
    installation without them falls back to the untrained network (seeded) and says so."""
    import mipnet
    from ..model import pretrained

    if weights:
        return mipnet.load(weights).eval()
    if pretrained.available():
        return mipnet.MIPNet.pretrained()
    if not quiet:
        print("WARNING: this installation ships no trained MIPNet weights: this is the UNTRAINED network "
              f"(random initialisation, seed {UNTRAINED_SEED}); its disparities are not meaningful. "
              "Pass --weights FILE.safetensors to use trained weights.", file=sys.stderr)
    mipnet.manual_seed(UNTRAINED_SEED)
    return mipnet.MIPNet().eval()


def describe_weights(weights: str | None, history: bool = False) -> list[str]:
    """Lines saying what a weights file (default: the shipped one) was trained on: how it was made and its last
    run's recipe, its steps and validation table; ``history``: every run of its lineage and every command."""
    from ..model import pretrained
    from ..serialization import load_safetensors

    if weights:
        meta, label = pretrained.decode_metadata(load_safetensors(weights)[1]), weights
    elif pretrained.available():
        meta, label = pretrained.pretrained_info(), f"shipped ({pretrained.PRETRAINED_PATH.name})"
    else:
        return ["weights: none shipped (untrained network)"]
    lines = [f"weights: {label}"]
    trained, commands, validation = meta.get("trained"), meta.get("commands"), meta.get("validation")
    # A mean of weights describes each file it averages after "; the last: ", and each run after "; then ":
    # the first clause says how this file was made, the last "then" clause is the newest run's recipe.
    nested = isinstance(trained, str) and "; the last: " in trained
    if nested and not history:
        last_run = trained.rsplit("; then ", 1)[-1]
        lines.append(f"  trained: {trained.partition('; the last: ')[0]}; the newest run: {last_run}")
    elif trained is not None:
        lines.append(f"  trained: {trained}")
    lines += [f"  {key}: {meta[key]}" for key in ("step", "generator_version", "mipnet_version") if key in meta]
    if isinstance(commands, list) and commands and not history:
        lines.append(f"  commands: {len(commands)}, the last: {commands[-1]}")
    elif isinstance(commands, list):
        lines += ["  commands:"] + [f"    {command}" for command in commands]
    elif commands is not None:
        lines.append(f"  commands: {commands}")
    rows = {}
    if isinstance(validation, dict):
        rows = {name: row for name, row in validation.items() if isinstance(row, dict) and {"epe", "bad3"} <= set(row)}
    if rows:
        width = max(map(len, rows))
        lines.append("  validation (EPE px / bad-3 %):")
        lines += [f"    {name:<{width}}  {row['epe']:.3f} / {row['bad3']:.1f}" for name, row in rows.items()]
    elif validation is not None:
        lines.append(f"  validation: {validation}")
    if not history and (nested or (isinstance(commands, list) and len(commands) > 1)):
        lines.append("  (mipnet info --history: every run of the lineage and every command)")
    return lines


def progress_bar(total: int, label: str):
    """A tqdm bar on stderr (pairs done, rate, ETA); on a non-terminal it updates at most every 30 s."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=label, unit="pair", file=sys.stderr, dynamic_ncols=True,
                mininterval=0.5 if sys.stderr.isatty() else 30.0)


#: What a user can cause (bad files, options, sizes, too little memory): one line, exit status 2.
#: Anything else is a bug in mipnet and keeps its traceback.
USER_ERRORS = (MipnetError, OSError, MemoryError)
EXIT_USAGE, EXIT_SOME_FAILED = 2, 1


def describe(error: BaseException) -> str:
    """A user error as one line of text that names the file involved."""
    if isinstance(error, OSError) and error.filename is not None:
        text = f"{error.filename}: {error.strerror or error}"
    elif isinstance(error, MemoryError) and not isinstance(error, MipnetError):
        text = f"out of memory ({error or 'an allocation failed'})"
    else:
        text = str(error) or type(error).__name__
    return " ".join(text.split())


def naming(files: tuple[str, ...], error: BaseException) -> str:
    """:func:`describe` of an error met on ``files``, prefixed with them unless it names one already."""
    message = describe(error)
    return message if any(f in message for f in files) else f"{' + '.join(files)}: {message}"


class PairError(MipnetError):
    """A user error met on one pair of images, re-raised with a message that names the pair's files."""


class Failures:
    """The pairs that failed in a run over many: each reported when it happens, all listed at the end."""

    def __init__(self, command: str, debug: bool):
        self.command, self.debug, self.items = command, debug, {}

    def attempt(self, files: tuple[str, ...], fn: Callable, *args):
        """``fn(*args)``, or None after recording the pair of ``files`` as failed if it raises a user error."""
        try:
            return fn(*args)
        except USER_ERRORS as error:
            self.add(files, error)
            return None

    def add(self, files: tuple[str, ...], error: BaseException) -> None:
        if self.debug:
            traceback.print_exc()
        self.items[files] = naming(files, error)
        print(f"{self.command}: skipped {self.items[files]}", file=sys.stderr)

    def report(self, total: int) -> int:
        """Lists the failures; the exit status (0 if none)."""
        if not self.items:
            return 0
        print(f"{self.command}: {len(self.items)} of {total} pairs failed:", file=sys.stderr)
        for message in self.items.values():
            print(f"  {message}", file=sys.stderr)
        return EXIT_SOME_FAILED


def _expand(pattern: str) -> list[str]:
    """The files a path or glob names, sorted; FileNotFoundError if there are none."""
    if any(c in pattern for c in "*?["):
        paths = sorted(p for p in glob.glob(pattern) if os.path.isfile(p))
        if not paths:
            raise FileNotFoundError(errno.ENOENT, "no file matches this pattern", pattern)
        return paths
    if not os.path.exists(pattern):
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), pattern)
    if not os.path.isfile(pattern):
        raise IsADirectoryError(errno.EISDIR, "not a file", pattern)
    return [pattern]


def read_pair(left_path: str, right_path: str) -> tuple[np.ndarray, np.ndarray]:
    """The two images of a stereo pair as RGB uint8; ShapeError naming both files if their sizes differ
    or are below the model's minimum."""
    from ..stereo import io
    from ..model.network import MIN_SIZE

    left, right = io.read_image(left_path), io.read_image(right_path)
    (lh, lw), (rh, rw) = left.shape[:2], right.shape[:2]
    if (lh, lw) != (rh, rw):
        raise ShapeError(f"{left_path} is {lh}x{lw} (HxW) but {right_path} is {rh}x{rw}: "
                         "the two images of a pair must have one size")
    if min(lh, lw) < MIN_SIZE:
        raise ShapeError(f"{left_path} is {lh}x{lw} (HxW): MIPNet needs images of at least {MIN_SIZE}x{MIN_SIZE}")
    return left, right


def cmd_infer(args: argparse.Namespace) -> int:
    from ..stereo import geometry, io, viz
    from ..stereo.confidence import match_confidence

    if (args.left is None) != (args.right is None):
        raise ArgumentError("give both -l/--left and -r/--right, or neither (bundled example pair)")
    if args.vmin is not None and args.vmax is not None and not args.vmin < args.vmax:
        raise ArgumentError(f"--vmin {args.vmin} must be below --vmax {args.vmax}")
    lefts = _expand(args.left) if args.left else [str(EXAMPLE_LEFT)]
    rights = _expand(args.right) if args.right else [str(EXAMPLE_RIGHT)]
    if len(lefts) != len(rights):
        raise ArgumentError(f"{len(lefts)} left images ({args.left}) but {len(rights)} right images ({args.right})")
    calib = io.read_calib(args.calib) if args.calib else None
    # a single pair is checked before the model loads, so that its error is the only line printed
    first = read_pair(lefts[0], rights[0]) if len(lefts) == 1 else None
    model = load_model(args.weights)
    out = Path(args.output_directory)
    out.mkdir(parents=True, exist_ok=True)

    def infer_pair(lp: str, rp: str, images: tuple | None = None) -> None:
        left, right = images or read_pair(lp, rp)
        disp = model(left, right, iters=tuple(args.iters), seed=args.seed, scale=args.scale)
        stem = out / Path(lp).stem
        if args.confidence or args.min_confidence is not None:
            confidence = match_confidence(left, right, disp)
            _write_npy(f"{stem}_conf.npy", confidence)
            io.write_image(f"{stem}_conf.png", viz.colorize(confidence, vmin=0.0, vmax=1.0, cmap="gray"))
            if args.min_confidence is not None:
                # pixels the images do not back are invalid (inf, the Middlebury convention)
                disp = np.where(confidence >= args.min_confidence, disp, np.float32(np.inf))
        _write_npy(f"{stem}_disp.npy", disp)
        io.write_pfm(f"{stem}_disp.pfm", disp)
        io.write_image(f"{stem}_disp.png", viz.colorize(disp, vmin=args.vmin, vmax=args.vmax))
        if calib is not None:
            depth = geometry.disparity_to_depth(disp, calib)
            _write_npy(f"{stem}_depth.npy", depth)
            points, colors = geometry.depth_to_points(depth, calib, image=left)
            io.write_ply(f"{stem}_points.ply", points, colors)

    if len(lefts) == 1:  # a single pair: its error is the command's error (status 2)
        try:
            infer_pair(lefts[0], rights[0], first)
        except USER_ERRORS as error:
            raise PairError(naming((lefts[0], rights[0]), error)) from error
        print(f"wrote 1 disparity map to {out}/")
        return 0
    failures = Failures("mipnet infer", args.debug)
    with progress_bar(len(lefts), "infer") as progress:
        for lp, rp in zip(lefts, rights):
            failures.attempt((lp, rp), infer_pair, lp, rp)
            progress.set_postfix_str(Path(lp).name, refresh=False)
            progress.update(1)
    print(f"wrote {len(lefts) - len(failures.items)} disparity map(s) to {out}/")
    return failures.report(len(lefts))


def _write_npy(path: str, array: np.ndarray) -> None:
    from ..utils.files import atomic_write

    with atomic_write(path) as f:
        np.save(f, array)


def cmd_info(args: argparse.Namespace) -> int:
    import mipnet

    if args.measure and not args.size:
        raise ArgumentError("--measure needs --size H W")
    model = load_model(args.weights, quiet=True)
    print(f"mipnet {mipnet.__version__}  threads={mipnet.get_num_threads()}  dtype={model.dtype}")
    print("\n".join(describe_weights(args.weights, args.history)))
    print("config: " + ", ".join(f"{k}={v}" for k, v in vars(model.config).items()))
    counts: dict[str, int] = {}
    for name, p in model.named_parameters():
        parts = name.split(".")
        key = "encoder.fuse (iAFF)" if ".fuse." in name else ".".join(parts[:2])
        counts[key] = counts.get(key, 0) + p.data.size
    width = max(map(len, counts))
    print("parameters:")
    for key, n in counts.items():
        print(f"  {key:<{width}}  {n:>10,}")
    print(f"  {'total':<{width}}  {model.num_parameters():>10,}")
    if args.size:
        from ..model import memory

        room = memory.available_memory()
        print("memory (estimated" + (f"; available now {memory.format_bytes(room[0])}, {room[1]}):" if room else "):"))
        for mode in ("eval", "train"):
            needed = memory.estimate(*args.size, args.batch, mode, args.iters, model)
            line = "  " + needed.describe()
            if args.measure and room and needed.activations > room[0]:
                line += "; not measured: more than is available"
            elif args.measure:
                measured = memory.measure_peak(*args.size, args.batch, mode, args.iters)
                line += (f"; measured {memory.format_bytes(measured)} ({100 * (needed.total / measured - 1):+.0f}%, "
                         "fresh process, default float32 model)")
            print(line, flush=True)
    return 0


def open_dataset(args: argparse.Namespace):
    """The evaluation pairs named by ``--dataset`` (``--root`` for the on-disk sets and fetched real pairs)."""
    from ..data.registry import open_dataset as open_registered

    entry = DATASETS[args.dataset]
    if entry.underwater and args.preset is None:
        raise ArgumentError(f"--dataset {args.dataset} needs --preset (clear, coastal, turbid, low_light, random)")
    if entry.kind == "disk" and not args.root:
        raise ArgumentError(f"--dataset {args.dataset} needs --root DIR")
    return open_registered(args.dataset, root=args.root, split="test", size=tuple(args.size), seed=args.seed,
                           count=args.n, water=args.preset, resolution=args.resolution)


def cmd_fetch(args: argparse.Namespace) -> int:
    from ..data.real import fetch_real

    print(f"mipnet fetch: {args.name} is in {fetch_real(args.name, root=args.root)}")
    return 0


def cmd_eval(args: argparse.Namespace) -> int:
    from ..model import pretrained
    from ..stereo.evaluation import format_table, mipnet_rows, sgbm_rows

    methods = set(args.methods.split(","))
    if not methods or not methods <= {"mipnet", "sgbm"}:
        raise ArgumentError(f"--methods {args.methods!r}: expected a comma-separated list of mipnet, sgbm")
    dataset = open_dataset(args)
    count = min(len(dataset), args.max_pairs) if args.max_pairs else len(dataset)
    failures = Failures("mipnet eval", args.debug)

    def pairs():
        """One fresh pass per method over the pairs that can be read (the others are recorded)."""
        for i in range(count):
            pair = failures.attempt((f"pair {i}",), dataset.__getitem__, i)
            if pair is not None:
                yield pair

    def on_error(name, error: Exception) -> None:
        if not isinstance(error, USER_ERRORS):
            raise error
        failures.add((str(name),), error)

    rows = []
    if "mipnet" in methods:
        model = load_model(args.weights)
        with progress_bar(count, "mipnet") as progress:
            def predict(left, right):
                disp = model(left, right, iters=tuple(args.iters), scale=args.scale)
                progress.update(1)
                return disp

            trained = bool(args.weights) or pretrained.available()
            rows += mipnet_rows(pairs(), predict, "MIPNet" + ("" if trained else " (untrained)"), args.aggregation,
                                args.min_confidence, on_error)
    if "sgbm" in methods:
        full, covered = sgbm_rows(pairs(), aggregation=args.aggregation, on_error=on_error)
        rows += [{**full, "method": "SGBM (full coverage)"}, {**covered, "method": "SGBM (covered)"}]
    name = args.dataset + (f" ({args.preset})" if args.preset else "")
    print(f"{name}: {count} pairs, {args.aggregation} over images; bad-x and d1 in percent, epe/a90/rms in px")
    print(format_table(rows))
    return failures.report(count)


class CommandLineError(Exception):
    """A command line argparse rejects (unknown option, bad value); ``prog`` is ``mipnet <command>``."""

    def __init__(self, prog: str, message: str):
        super().__init__(message)
        self.prog, self.message = prog, message


class Parser(argparse.ArgumentParser):
    """argparse with the error handling of :func:`main`: a rejected command line raises
    :class:`CommandLineError` (one line, no usage dump), and every (sub)command accepts ``--debug``.
    Subparsers made with ``add_subparsers().add_parser`` are of this class too."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # SUPPRESS: a subcommand's default does not overwrite a --debug given before the subcommand
        self.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                          help="on an error, print the Python traceback too")

    def error(self, message: str):
        raise CommandLineError(self.prog, message)


def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def positive_float(text: str) -> float:
    value = float(text)
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def unit_fraction(text: str) -> float:
    value = float(text)
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {text}")
    return value


class Iters(argparse.Action):
    """``--iters N16 N4``: N16 >= 1 iterations at 1/16, N4 >= 0 at 1/4."""

    def __call__(self, parser, namespace, values, option_string=None):
        n16, n4 = values
        if n16 < 1 or n4 < 0:
            parser.error(f"argument {option_string}: needs N16 >= 1 and N4 >= 0, got {n16} {n4}")
        setattr(namespace, self.dest, (n16, n4))


class ImageSize(argparse.Action):
    """``--size H W``: an image size the model accepts (both sides >= MIN_SIZE)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from ..model.network import MIN_SIZE

        h, w = values
        if min(h, w) < MIN_SIZE:
            parser.error(f"argument {option_string}: {h}x{w} (HxW) is below the minimum {MIN_SIZE}x{MIN_SIZE}")
        setattr(namespace, self.dest, (h, w))


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="mipnet", description="MIPNet stereo matching on the CPU (Rust engine).")
    p.add_argument("--threads", type=positive_int, default=None,
                   help="kernel threads (default: all cores / MIPNET_NUM_THREADS)")
    sub = p.add_subparsers(dest="command", required=True)

    inf = sub.add_parser("infer", help="disparity (and depth, point cloud) for stereo pairs")
    inf.add_argument("-l", "--left", help="left image or glob (default: the bundled example pair)")
    inf.add_argument("-r", "--right", help="right image or glob, same order as --left")
    inf.add_argument("-o", "--output_directory", "--output-directory", default="mipnet_out")
    inf.add_argument("--weights", help="weights file (.safetensors written by MIPNet.save)")
    inf.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"), action=Iters)
    inf.add_argument("--calib", help="calib.txt (Middlebury/ETH3D) or K.txt: also write depth and a point cloud")
    inf.add_argument("--vmin", type=float, default=None, help="colour range (default: 1st-99th percentile)")
    inf.add_argument("--vmax", type=float, default=None)
    inf.add_argument("--seed", type=int, default=20, help="seed of the gamma initialisation (default 20)")
    inf.add_argument("--scale", type=positive_float, default=1.0,
                     help="resize the pair by this factor before the network, the disparity back (default 1; "
                          "e.g. 0.5 for photographs whose disparities exceed ~160 px)")
    inf.add_argument("--confidence", action="store_true",
                     help="also write the match confidence (NAME_conf.npy / .png): near 1 where both views show the "
                          "same texture at the disparity, near 0 where the disparity is a guess (open water, sky, "
                          "occlusions)")
    inf.add_argument("--min-confidence", type=unit_fraction, default=None, metavar="C",
                     help="mark pixels whose match confidence is below C invalid (inf in .npy/.pfm, black in .png, "
                          "no depth or point); 0.5 keeps ~97%% of the pixels in air and drops open water under a "
                          "veil (docs/training.md); implies --confidence")
    inf.set_defaults(func=cmd_infer)

    info = sub.add_parser("info", help="config, parameter counts per module, thread count, memory estimates")
    info.add_argument("--weights", help="weights file to describe")
    info.add_argument("--history", action="store_true",
                      help="print every training run of the weights' lineage and every command, not only the newest")
    info.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), action=ImageSize,
                      help="also print the peak memory of an eval forward and a training step at this image size")
    info.add_argument("--batch", type=positive_int, default=1, help="image pairs per pass for --size (default 1)")
    info.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"), action=Iters)
    info.add_argument("--measure", action="store_true",
                      help="with --size: also run each pass in a fresh process and print its measured peak memory")
    info.set_defaults(func=cmd_info)

    ev = sub.add_parser("eval", help="metrics of MIPNet and OpenCV SGBM on a dataset")
    ev.add_argument("--dataset", required=True, choices=list(DATASETS))
    ev.add_argument("--root", help="dataset root folder (official layout)")
    ev.add_argument("--weights", help="weights file (.safetensors written by MIPNet.save)")
    ev.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"), action=Iters)
    ev.add_argument("--scale", type=positive_float, default=1.0, help="MIPNet's input resize factor (as infer)")
    ev.add_argument("--methods", default="mipnet,sgbm", help="comma-separated: mipnet, sgbm")
    ev.add_argument("--min-confidence", type=unit_fraction, default=None, metavar="C",
                    help="add a row scoring MIPNet only where its match confidence is >= C (as infer), beside "
                         "SGBM's covered row")
    ev.add_argument("--preset", choices=("clear", "coastal", "turbid", "low_light", "random"),
                    help="underwater preset (random: water drawn around the presets per pair)")
    ev.add_argument("--n", type=positive_int, default=50, help="number of generated pairs (synthetic sets)")
    ev.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"), action=ImageSize,
                    help="generated pair size")
    ev.add_argument("--seed", type=int, default=1_000_000,
                    help="pair seed of the first generated pair (default 1000000: held out from training)")
    ev.add_argument("--resolution", default="H", choices=("F", "H", "Q"), help="MiddEval3 resolution")
    ev.add_argument("--max-pairs", type=positive_int, default=None, help="evaluate only the first N pairs")
    ev.add_argument("--aggregation", default="mean", choices=("mean", "pooled"),
                    help="mean of per-image metrics (ETH3D) or pooled over all pixels (KITTI)")
    ev.set_defaults(func=cmd_eval)

    fetch = sub.add_parser("fetch", help="download a real evaluation pair that no package ships ready (cones)")
    fetch.add_argument("name", choices=("cones",))
    fetch.add_argument("--root", help="folder to keep it in (default $MIPNET_REAL_DATA or ~/.cache/mipnet/real)")
    fetch.set_defaults(func=cmd_fetch)

    from .train import add_parser

    add_parser(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Runs one ``mipnet`` command; its exit status: 0 done, 1 some pairs of a run failed (listed),
    2 a user error (one line on stderr; ``--debug`` adds the traceback)."""
    try:
        args, unknown = build_parser().parse_known_args(argv)
        if unknown:  # reported against the subcommand they were given to, not the top-level parser
            raise CommandLineError(f"mipnet {args.command}", f"unrecognized arguments: {' '.join(unknown)}")
    except CommandLineError as error:
        print(f"{error.prog}: error: {error.message} (see {error.prog} --help)", file=sys.stderr)
        return EXIT_USAGE
    args.debug = debug = getattr(args, "debug", False)  # absent unless given (SUPPRESS default)
    try:
        if args.threads:
            import mipnet

            mipnet.set_num_threads(args.threads)
        return args.func(args)
    except USER_ERRORS as error:
        if debug:
            traceback.print_exc()
        prefix = f"mipnet {args.command}: "
        message = describe(error)
        # messages that already name the command (raised for the command line) are not prefixed twice
        print(prefix + "error: " + (message[len(prefix):] if message.startswith(prefix) else message), file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
