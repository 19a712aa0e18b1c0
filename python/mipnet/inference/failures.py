"""What a user can cause, and its description in one line that names the file involved.

``mipnet``'s commands print these descriptions (``mipnet <command>: error: <what>``, :mod:`mipnet.cli.app`), a run
over many pairs lists them per failed pair (:class:`mipnet.cli.common.Failures`), and the Ray pipeline writes them
to ``failures.jsonl`` (:mod:`mipnet.distributed.infer`).
"""

from __future__ import annotations

from ..errors import MipnetError

#: What a user can cause (bad files, options, sizes, too little memory): one line, exit status 2.
#: Anything else is a bug in mipnet and keeps its traceback.
USER_ERRORS = (MipnetError, OSError, MemoryError)


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
