"""Automatic mixed precision: ``mipnet.autocast``, as ``torch.autocast("cpu", dtype=torch.bfloat16)``.

Inside ``with mipnet.autocast(dtype="bfloat16"):`` every float32 convolution (and so every GEMM of the
network) rounds its input and weights to bfloat16 as it packs them and sums their products in float32 with the
CPU's bf16 dot products (AVX512_BF16: AMD Zen 4 and later, Intel Cooper Lake and Sapphire Rapids and later);
its output stays float32. Everything else (norms, softmax, correlation and sampling, the disparity state)
runs in float32 as before. On a CPU without bf16 dot products (or with ``MIPNET_ISA`` below avx512) the context
changes nothing and says so once, with a warning. Unlike torch's CPU autocast, outputs are not rounded to
bfloat16: only the products are, which is where the time goes.
"""

from __future__ import annotations

import threading
import warnings
from contextlib import ContextDecorator

from . import _core
from .errors import ArgumentError

__all__ = ["autocast", "bf16_active"]

_DTYPES = ("bfloat16", "bf16")
_local = threading.local()
_warned = False


def bf16_active() -> bool:
    """Whether this thread is inside an enabled ``autocast`` on a CPU that has bf16 dot products."""
    return getattr(_local, "depth", 0) > 0 and _core.bf16_supported()


class autocast(ContextDecorator):
    """``with mipnet.autocast(dtype="bfloat16"):`` (or as a decorator): float32 convolutions take bfloat16
    products with float32 sums in this thread.

    Parameters
    ----------
    device_type : str, default "cpu"
        Only "cpu" (the argument mirrors ``torch.autocast``).
    dtype : str, default "bfloat16"
        "bfloat16" (or "bf16"), the only reduced type mipnet computes in.
    enabled : bool, default True
        False makes the context a no-op (as torch's).

    Raises
    ------
    ArgumentError
        Another device type or dtype.
    """

    def __init__(self, device_type: str = "cpu", dtype: str = "bfloat16", enabled: bool = True):
        if device_type != "cpu":
            raise ArgumentError(f"mipnet.autocast: device_type must be 'cpu', got {device_type!r}")
        if str(dtype).removeprefix("torch.") not in _DTYPES:
            raise ArgumentError(f"mipnet.autocast: dtype must be 'bfloat16', got {dtype!r}")
        self.enabled = bool(enabled)

    def __enter__(self) -> "autocast":
        if self.enabled:
            _warn_if_unsupported()
            _local.depth = getattr(_local, "depth", 0) + 1
        return self

    def __exit__(self, *exc) -> None:
        if self.enabled:
            _local.depth -= 1


def _warn_if_unsupported() -> None:
    """One warning per process when bf16 was asked for on a CPU (or ISA path) without it."""
    global _warned
    if not _warned and not _core.bf16_supported():
        _warned = True
        warnings.warn(f"mipnet.autocast: this CPU has no bfloat16 dot products on the {_core.simd_isa()} path "
                      "(AVX512_BF16 is needed); convolutions run in float32", RuntimeWarning, stacklevel=3)
