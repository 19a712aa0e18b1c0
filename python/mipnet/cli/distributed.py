"""``--ray``: ``mipnet infer`` and ``mipnet train`` on a Ray cluster (:mod:`mipnet.distributed`, docs/distributed.md).

The flags, and the few lines that turn the parsed command line into a call of :func:`mipnet.distributed.infer_dataset`
or :func:`mipnet.distributed.fit`. Without Ray installed, ``--ray`` is a one-line error naming the extra.
"""

from __future__ import annotations

import argparse
import functools
import sys
from typing import Callable

from ..distributed.cluster import require_ray
from ..errors import ArgumentError
from .common import Failures, PairError, load_model, positive_int

RAY_HELP = ("run on a Ray cluster: with no ADDRESS the one in RAY_ADDRESS or started here by `ray start`, else a "
            "new local one; 'auto': an existing cluster only; HOST:6379 or ray://HOST:10001: that cluster "
            "(pip install 'mipnet[ray]'; docs/distributed.md)")


def add_ray_arguments(parser: argparse.ArgumentParser, workers_help: str | None = None) -> None:
    """``--ray [ADDRESS]`` on ``parser``, and ``--workers N`` (dest ``ray_workers``), the number of Ray actors, where
    ``workers_help`` is given (``mipnet train`` has its own ``--workers``, which counts actors with ``--ray``)."""
    parser.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS", help=RAY_HELP)
    if workers_help is not None:
        parser.add_argument("--workers", dest="ray_workers", type=positive_int, default=None, metavar="N",
                            help=workers_help)


def _address(args: argparse.Namespace) -> str | None:
    """The Ray address of ``--ray [ADDRESS]``: None for the bare flag (ray.init's own search)."""
    return args.ray or None


def _check(args: argparse.Namespace) -> bool:
    """Whether ``--ray`` was given (Ray then importable: ArgumentError naming the extra otherwise)."""
    if args.ray is None:
        if getattr(args, "ray_workers", None) is not None:
            raise ArgumentError("--workers needs --ray (the number of Ray actors)")
        return False
    require_ray()
    return True


def infer_on_ray(args: argparse.Namespace, calib, read: Callable) -> int | None:
    """``mipnet infer --ray``: the run's exit status as the single-process command's (0; 1 when some pairs
    failed, listed; a single pair's failure is the command's error, status 2); None without ``--ray``."""
    from ..distributed import infer_dataset
    from ..inference.outputs import OutputOptions

    if not _check(args):
        return None
    if args.batch_size is not None:
        raise ArgumentError("--batch-size does not apply with --ray: each actor runs its pairs one at a time "
                            "(the outputs of --batch-size 1), and the actors run in parallel")
    options = OutputOptions(confidence=args.confidence, min_confidence=args.min_confidence, vmin=args.vmin,
                            vmax=args.vmax, z_far=args.z_far)
    report = infer_dataset(args.left, args.right, args.output_directory, address=_address(args),
                           workers=args.ray_workers, iters=tuple(args.iters), weights=load_model(args.weights),
                           seed=args.seed, scale=args.scale, calib=calib, options=options, read=read,
                           precision=args.precision)
    skipped = f" (skipped {len(report.skipped)} pair(s) whose outputs were complete)" if report.skipped else ""
    print(f"wrote {len(report.run)} disparity map(s) to {args.output_directory}/{skipped}")
    if report.total == 1 and report.failed:
        raise PairError(report.failed[0]["reason"])
    failures = Failures("mipnet infer", args.debug)
    for record in report.failed:
        if args.debug:
            print(record["traceback"], file=sys.stderr, end="")
        failures.record((record["left"], record["right"]), record["reason"])
    return failures.report(report.total)


def trainer(args: argparse.Namespace) -> Callable:
    """The training function of ``mipnet train``: :func:`mipnet.training.fit.fit`, or with ``--ray``
    :func:`mipnet.distributed.fit` on that cluster with ``--workers`` actors.

    With ``--ray``, ``--workers N`` counts Ray actors, as the issue's interface and torch's DDP launchers have it;
    the data then loads in the run's own settings' loader processes (the preset's or the resumed run's), so the
    flag is taken off ``args`` before the training settings are read from it."""
    if not _check(args):
        from ..training.fit import fit

        return fit
    from ..distributed import fit as fit_on_ray

    actors, args.workers = args.workers, None
    if actors is not None and actors < 1:
        raise ArgumentError(f"--workers with --ray counts Ray actors: give at least 1, got {actors}")
    return functools.partial(fit_on_ray, address=_address(args), workers=actors)
