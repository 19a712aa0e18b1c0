"""Small file helpers shared by mipnet's writers."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from typing import IO

# The process umask, read once: mkstemp creates files with mode 0600, and the finished file
# should get the permissions a plain ``open(path, "w")`` would have given it.
_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file next to ``path``; move it onto ``path`` only if the block succeeds.

    Readers never see a half-written file: the data goes to a temporary file in the same
    directory (so the final ``os.replace`` is an atomic rename on one file system). If the
    block raises, the temporary file is deleted and ``path`` is left as it was.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    mode : str
        ``"wb"`` (binary, default) or ``"w"`` (text, UTF-8).

    Yields
    ------
    file object
        The open temporary file.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_write: mode must be 'wb' or 'w', got {mode!r}")
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=directory, prefix="." + os.path.basename(path) + ".", suffix=".tmp")
    try:
        encoding = "utf-8" if mode == "w" else None
        with os.fdopen(fd, mode, encoding=encoding) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
