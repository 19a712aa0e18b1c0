"""The ``mipnet`` command line: ``infer``, ``eval``, ``train``, ``adapt``, ``info``, ``fetch``, ``export``. Also ``python -m mipnet``.

One module a subcommand (:mod:`.infer`, :mod:`.eval`, :mod:`.train`, :mod:`.adapt`, :mod:`.info`, :mod:`.fetch`, :mod:`.export`), each
with ``add_parser(sub)`` and ``run(args)``; what they share is in :mod:`.common`. This module builds the
parser and runs a command.

Errors are handled once, in :func:`main`, for every subcommand: a user error (a missing, unreadable
or corrupt file, images of different sizes, bad calibration or weights, a bad flag value, a missing
optional dependency, not enough memory) prints one line ``mipnet <command>: error: <what>`` and exits
with status 2; ``--debug`` (before or after the command) prints the traceback as well. A run over many
pairs goes on past a pair that fails, lists the failures at the end and exits with status 1.
"""

from __future__ import annotations

import argparse
import sys
import traceback
from typing import Sequence

from . import adapt, eval as eval_command, export, fetch, info, infer, train
from ..inference.failures import describe
from .common import EXIT_USAGE, USER_ERRORS, CommandLineError, Parser, positive_int

#: the subcommands, in the order ``mipnet --help`` lists them
COMMANDS = (infer, info, eval_command, fetch, train, adapt, export)


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    p = Parser(prog="mipnet", description="MIPNet stereo matching on the CPU (Rust engine).")
    p.add_argument("--version", action="version", version=f"mipnet {__version__}",
                   help="print mipnet's version and exit")
    p.add_argument("--threads", type=positive_int, default=None,
                   help="kernel threads (default: all cores / MIPNET_NUM_THREADS)")
    sub = p.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
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
        from .. import _core

        _core.simd_isa()  # a bad MIPNET_ISA is an ArgumentError (as from every kernel): reported before any work
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
