"""A reusable fuzzing harness for file readers, on hypothesis.

A reader passes when, for any bytes, it either returns a value or raises one of its documented
exceptions: never another exception, never a hang, never an allocation out of proportion to the file
(a lying header). Use it for any reader that takes a path::

    from hypothesis import given
    from fuzzing import assert_reads_or_raises, fuzz_settings, mutations

    SEEDS = [valid_file_bytes, truncated_file_bytes]

    @fuzz_settings(200)
    @given(mutations(SEEDS))
    def test_my_reader_never_fails_badly(data):
        assert_reads_or_raises(my_reader, data, allowed=(FormatError,))

The number of examples is bounded (``fuzz_settings(n)``; scale every count with the environment
variable ``MIPNET_HYPOTHESIS_SCALE`` for a longer local run). Failures shrink to a minimal input.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import struct
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any, Callable, Sequence

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

#: A reader that runs longer than this on a small input is taken to hang.
READER_TIMEOUT_S = 10.0
#: The most a reader may allocate on a fuzz input (tracemalloc peak: numpy and Python objects).
MAX_ALLOC_BYTES = 64 * 2**20

#: Numbers that break naive size arithmetic: zero, negatives, 32/64-bit limits, 10^12 elements.
NASTY_INTS = (0, 1, -1, 2**15, 2**16, 2**31 - 1, 2**31, 2**32, 2**53 + 1, 2**63 - 1, 2**63, 2**64, 10**6, 10**12, 10**30)
NASTY_FLOATS = ("0", "-0", "nan", "inf", "-inf", "1e999", "1e-400", "-1", "3.5", "1e12")


class ReaderHang(Exception):
    """The reader did not return within its time limit."""


def scale() -> float:
    """Multiplier of every example count (``MIPNET_HYPOTHESIS_SCALE``, default 1)."""
    return float(os.environ.get("MIPNET_HYPOTHESIS_SCALE", "1"))


def fuzz_settings(max_examples: int, **overrides: Any) -> settings:
    """hypothesis settings for a bounded fuzz test: ``max_examples`` (times :func:`scale`), no per-example
    deadline (the harness has its own time limit), health checks that suit generated files."""
    return settings(max_examples=max(1, int(max_examples * scale())), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large], **overrides)


@contextlib.contextmanager
def time_limit(seconds: float):
    """Raises :class:`ReaderHang` inside the block after ``seconds`` (main thread only; elsewhere no limit)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def expire(signum, frame):
        raise ReaderHang(f"no result after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def allocation_peak():
    """Yields a dict whose ``"peak"`` is, after the block, the most memory traced inside it (bytes)."""
    result = {"peak": 0}
    started = not tracemalloc.is_tracing()
    if started:
        tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    try:
        yield result
    finally:
        result["peak"] = tracemalloc.get_traced_memory()[1] - base
        if started:
            tracemalloc.stop()


def assert_reads_or_raises(reader: Callable[[str], Any], data: bytes, allowed: tuple[type[BaseException], ...], *,
                           suffix: str = "", names_file: bool = True, check: Callable[[Any], None] | None = None,
                           max_bytes: int = MAX_ALLOC_BYTES, timeout: float = READER_TIMEOUT_S) -> Any:
    """Writes ``data`` to a file and reads it with ``reader(path)``.

    Passes if the reader returns (then ``check(result)`` runs, if given) or raises one of ``allowed``
    (whose message names the file when ``names_file``). Fails on any other exception, on a run longer
    than ``timeout`` seconds, and on a traced allocation peak above ``max_bytes``. Returns the result,
    or None when an allowed exception was raised.
    """
    what = f"{getattr(reader, '__name__', reader)} on {len(data)} bytes {data[:48]!r}"
    start = time.perf_counter()
    with as_file(data, suffix) as path, allocation_peak() as alloc:
        try:
            with time_limit(timeout):
                result = reader(path)
        except allowed as error:
            if names_file:
                assert path in str(error), f"{what}: the error does not name the file: {error}"
            result = None
        except ReaderHang as error:
            raise AssertionError(f"{what}: hangs ({error})") from None
        except Exception as error:
            raise AssertionError(f"{what}: raised {type(error).__name__}: {error}") from error
    assert alloc["peak"] <= max_bytes, (f"{what}: allocated {alloc['peak']} bytes (limit {max_bytes}) "
                                        f"in {time.perf_counter() - start:.2f} s")
    if result is not None and check is not None:
        check(result)
    return result


@contextlib.contextmanager
def as_file(data: bytes, suffix: str = ""):
    """Yields the path of a temporary file holding ``data`` (deleted afterwards)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"input{suffix}"
        path.write_bytes(data)
        yield str(path)


def written_bytes(write: Callable, *args: Any, suffix: str = "", **kwargs: Any) -> bytes:
    """The bytes ``write(path, *args, **kwargs)`` puts in a file (a seed corpus from a writer)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"seed{suffix}"
        write(path, *args, **kwargs)
        return path.read_bytes()


# ------------------------------------------------------------------------------- input strategies

def _digit_runs(data: bytes) -> list[tuple[int, int]]:
    return [m.span() for m in re.finditer(rb"-?\d+(?:\.\d+)?", data)]


@st.composite
def _mutate(draw, data: bytes) -> bytes:
    """One edit of ``data``: truncate, overwrite, insert, delete, duplicate a slice, swap a number in the
    text for a nasty one, or overwrite 4 or 8 bytes with a nasty binary integer."""
    b = bytearray(data)
    kind = draw(st.sampled_from(("truncate", "overwrite", "insert", "delete", "duplicate", "number", "binary")))
    # a position inside the data (or its end)
    at = draw(st.integers(0, len(b)))
    if kind == "truncate":
        return bytes(b[:at])
    if kind == "overwrite":
        chunk = draw(st.binary(min_size=1, max_size=8))
        b[at:at + len(chunk)] = chunk
    elif kind == "insert":
        b[at:at] = draw(st.binary(min_size=1, max_size=16))
    elif kind == "delete":
        del b[at:at + draw(st.integers(1, 64))]
    elif kind == "duplicate":
        # a slice starting at `at`, copied to just after itself
        piece = b[at:at + draw(st.integers(1, 256))]
        b[at + len(piece):at + len(piece)] = piece
    elif kind == "number":
        runs = _digit_runs(bytes(b))
        if runs:
            begin, end = draw(st.sampled_from(runs))
            value = draw(st.sampled_from(NASTY_INTS + NASTY_FLOATS))
            b[begin:end] = str(value).encode()
    else:
        width = draw(st.sampled_from((4, 8)))
        value = draw(st.sampled_from([v for v in NASTY_INTS if 0 <= v < 2 ** (8 * width)]))
        b[at:at + width] = value.to_bytes(width, "little")
    return bytes(b)


@st.composite
def _mutated(draw, seeds: Sequence[bytes], max_edits: int) -> bytes:
    data = draw(st.sampled_from(list(seeds)))
    for _ in range(draw(st.integers(0, max_edits))):
        data = draw(_mutate(data))
    return data


def mutations(seeds: Sequence[bytes], max_edits: int = 4, raw_max_size: int = 512) -> st.SearchStrategy[bytes]:
    """Seed files (the corpus) with up to ``max_edits`` random edits each, or raw random bytes.
    Shrinks towards the first seed with no edits."""
    return st.one_of(_mutated(seeds, max_edits), st.binary(max_size=raw_max_size))


def le_u64(value: int) -> bytes:
    """An unsigned 64-bit little-endian integer (as in a safetensors header length)."""
    return struct.pack("<Q", value)
