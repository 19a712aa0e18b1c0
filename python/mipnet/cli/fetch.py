"""``mipnet fetch``: download a real evaluation pair that no package ships ready (``cones``).

    mipnet fetch cones                                   # through pip, from the index pip is configured for
    mipnet fetch cones --source pandora-1.9.0.tar.gz     # from a copy of the package (a path or a URL)

The pair comes from a source package on the package index; pip finds it (the user's index, mirror, proxy
and certificates, as ``pip download`` would), and mipnet checks the file's SHA-256 (see
:func:`mipnet.data.real.fetch_real`).
"""

from __future__ import annotations

import argparse


def add_parser(sub) -> argparse.ArgumentParser:
    """Registers ``fetch`` on the ``mipnet`` sub-command parsers."""
    p = sub.add_parser("fetch", help="download a real evaluation pair that no package ships ready (cones)",
                       description="Download a real evaluation pair once, through pip and the package index it "
                                   "is configured for; the file's SHA-256 is checked.")
    p.add_argument("name", choices=("cones",), help="the pair: cones (Middlebury 2003, from pandora's source package)")
    p.add_argument("--root", metavar="DIR",
                   help="folder to keep it in (default $MIPNET_REAL_DATA or ~/.cache/mipnet/real)")
    p.add_argument("--source", metavar="FILE_OR_URL",
                   help="take the source package from this copy (a path or a URL) instead of asking pip; "
                        "its SHA-256 must match")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from ..data.real import fetch_real

    print(f"mipnet fetch: {args.name} is in {fetch_real(args.name, root=args.root, url=args.source)}")
    return 0
