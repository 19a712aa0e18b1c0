"""The allocator policy for training: large blocks go back to the system when freed.

Every block of 4 MiB or more that the Rust core allocates passes through its cache (``src/alloc.rs``),
which keeps freed blocks for reuse up to the high-water mark of bytes in use and hands the rest back
to glibc. glibc's malloc serves a request below its mmap threshold from its heap, and the threshold
rises with the largest block freed so far (up to 32 MiB), so after the first step nearly every
tensor of a training step lives in glibc's heap, and what the cache hands back stays there. The
backward frees the forward's activations in the reverse order while it allocates gradients of other
sizes: the freed memory stays in the process in holes the new blocks do not fit, and the resident
memory grows during every backward and from step to step (256x512, batch 2, (4, 4): 3.2 GiB at the
first step, 3.6 GiB by the fifth). With a fixed threshold of 4 MiB every activation map of that
size gets its own mapping and is unmapped when freed: the same steps stay at 2.8 GiB.

Eval keeps glibc's default: reusing heap memory avoids the page faults of fresh mappings (384x512
eval measured 1.71 s against 1.44 with the fixed threshold, for no gain in peak memory). So the switch
happens once, when the first op is recorded for a backward (:meth:`mipnet.autograd.Function.apply`),
and holds for the rest of the process. ``MIPNET_MALLOC=default`` (or setting glibc's own
``MALLOC_MMAP_THRESHOLD_``) leaves the allocator alone. Only glibc is touched; elsewhere it is a
no-op.
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["TRAINING_MMAP_THRESHOLD", "use_training_policy", "training_policy_active"]

#: Bytes from which a block is mapped on its own in training (glibc's ``M_MMAP_THRESHOLD``).
TRAINING_MMAP_THRESHOLD = 4 * 2**20
_M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter number (malloc.h)

_decided = False
_active = False


def _glibc_mallopt():
    """glibc's ``mallopt``, or None on another C library or system."""
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(None)
    if not hasattr(libc, "gnu_get_libc_version"):
        return None
    mallopt = libc.mallopt
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return mallopt


def use_training_policy() -> None:
    """Switch glibc to the training policy (once per process; later calls return at once)."""
    global _decided, _active
    if _decided:
        return
    _decided = True
    if os.environ.get("MIPNET_MALLOC", "").lower() == "default" or "MALLOC_MMAP_THRESHOLD_" in os.environ:
        return
    mallopt = _glibc_mallopt()
    _active = mallopt is not None and mallopt(_M_MMAP_THRESHOLD, TRAINING_MMAP_THRESHOLD) == 1


def training_policy_active() -> bool:
    """Whether this process runs with the training policy."""
    return _active
