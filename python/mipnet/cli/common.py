"""What the ``mipnet`` subcommands share: the model they run, argument types, and failure reporting.

Errors are handled once, in :func:`mipnet.cli.app.main`, for every subcommand: a user error
(:data:`USER_ERRORS`) prints one line ``mipnet <command>: error: <what>`` and exits with status
:data:`EXIT_USAGE`; a run over many pairs records each pair that fails in :class:`Failures`, goes on,
lists them at the end and exits with status :data:`EXIT_SOME_FAILED`.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import math
import sys
import traceback
from collections.abc import Iterator
from typing import Callable

from ..errors import ArgumentError, MipnetError
from ..inference.failures import USER_ERRORS, naming

UNTRAINED_SEED = 0

EXIT_USAGE, EXIT_SOME_FAILED = 2, 1


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


def require_module(module: str, package: str, needed_for: str, instead: str = "") -> None:
    """ArgumentError (one line: what to install, and ``instead``, a way to do without) unless ``module``
    imports. Called before any work, so that a missing optional dependency costs nothing."""
    try:
        importlib.import_module(module)
    except ImportError:
        alternative = f", or {instead}" if instead else ""
        raise ArgumentError(f"{needed_for} needs the {module} module: pip install {package}{alternative}") from None


def progress_bar(total: int | None, label: str, unit: str = "pair"):
    """A tqdm bar on stderr (``unit``s done, rate, ETA); on a non-terminal it updates at most every 30 s."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=label, unit=unit, file=sys.stderr, dynamic_ncols=True,
                mininterval=0.5 if sys.stderr.isatty() else 30.0)


# ---- failure reporting ----------------------------------------------------------------------------


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
        self.record(files, naming(files, error))

    def record(self, files: tuple[str, ...], message: str) -> None:
        """A failure described elsewhere (by a Ray actor, :mod:`mipnet.distributed.infer`)."""
        self.items[files] = message
        print(f"{self.command}: skipped {message}", file=sys.stderr)

    def report(self, total: int) -> int:
        """Lists the failures; the exit status (0 if none)."""
        if not self.items:
            return 0
        print(f"{self.command}: {len(self.items)} of {total} pairs failed:", file=sys.stderr)
        for message in self.items.values():
            print(f"  {message}", file=sys.stderr)
        return EXIT_SOME_FAILED


# ---- the parser and argument types ----------------------------------------------------------------


class CommandLineError(Exception):
    """A command line argparse rejects (unknown option, bad value); ``prog`` is ``mipnet <command>``."""

    def __init__(self, prog: str, message: str):
        super().__init__(message)
        self.prog, self.message = prog, message


class Parser(argparse.ArgumentParser):
    """argparse with the error handling of :func:`mipnet.cli.app.main`: a rejected command line raises
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


#: the help of every ``--iters`` that runs the network (infer, eval, info)
ITERS_HELP = "IPM iterations at the 1/16 and the 1/4 level (default 6 6; fewer: faster, coarser)"


def add_iters(parser: argparse.ArgumentParser) -> None:
    """``--iters N16 N4`` (default 6 6) on ``parser``."""
    parser.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"), action=Iters,
                        help=ITERS_HELP)


def add_precision(parser: argparse.ArgumentParser) -> None:
    """``--precision {fp32,bf16}`` (default fp32) on ``parser``: bf16 runs the network under
    ``mipnet.autocast(dtype="bfloat16")``."""
    parser.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                        help="bf16: convolutions in bfloat16 with float32 sums where the CPU has bf16 dot products "
                             "(AVX512_BF16), about 0.75x the time at a few hundredths of a pixel; elsewhere float32 "
                             "with a warning (default fp32)")


class ImageSize(argparse.Action):
    """``--size H W``: an image size the model accepts (both sides >= MIN_SIZE)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from ..model.network import MIN_SIZE

        h, w = values
        if min(h, w) < MIN_SIZE:
            parser.error(f"argument {option_string}: {h}x{w} (HxW) is below the minimum {MIN_SIZE}x{MIN_SIZE}")
        setattr(namespace, self.dest, (h, w))


class _StderrAboveProgressBar(logging.Handler):
    """Writes each record's message to the current ``sys.stderr`` through ``tqdm.write``, which moves the
    training progress bar out of the way and redraws it below."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm

            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # logging's contract: a handler reports its own failures
            self.handleError(record)


@contextlib.contextmanager
def show_training_log() -> Iterator[None]:
    """While ``mipnet train`` or ``mipnet adapt`` runs, the ``mipnet`` loggers' INFO and above (validation tables, a stop on a
    signal, skipped checkpoints) go to stderr as their bare messages, as the command has always shown them."""
    logger = logging.getLogger("mipnet")
    handler = _StderrAboveProgressBar(logging.INFO)
    handler.setFormatter(logging.Formatter("%(message)s"))
    level = logger.level
    logger.addHandler(handler)
    if level == logging.NOTSET or level > logging.INFO:
        logger.setLevel(logging.INFO)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
