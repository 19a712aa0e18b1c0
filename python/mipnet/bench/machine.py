"""The machine a speed figure was measured on: the CPU, mipnet's kernel path and the FMA peak measured now.

Every command that prints seconds (``python -m mipnet.bench ops`` and ``model``, ``scripts/step_time.py``,
``scripts/eval_time.py``, ``scripts/iteration_dial.py``) prints :func:`machine_header` first, because the CPU of
this project's machines changes between sessions and a VM's speed drifts: a time means something only beside the
CPU model and the peak measured in the same run.
"""

from __future__ import annotations

import os
from pathlib import Path

from .. import _core

__all__ = ["PEAK_DRIFT", "cpu_name", "fma_peak_gflops", "machine_header", "peak_drift_line"]

#: Relative change of the FMA peak between a run's start and its end beyond which the run is flagged.
PEAK_DRIFT = 0.15


def _cpuinfo_fields() -> tuple[dict[str, str], set[str]]:
    """(family and model fields, ISA flags) of the first processor in /proc/cpuinfo; empty off Linux."""
    ids: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() in ("cpu family", "model"):
                ids[key.strip()] = value.strip()
            elif key.strip() == "flags":
                return ids, set(value.split())
    except OSError:
        pass
    return ids, set()


def cpu_name() -> str:
    """The CPU's brand string with its vendor, and family and model where /proc/cpuinfo has them (a VM's
    brand string can be as bare as "Intel(R) Xeon(R) Processor": family and model tell the generation)."""
    info = _core.cpu_info()
    ids, _ = _cpuinfo_fields()
    detail = [info["vendor"]]
    if ids:
        detail.append(f"family {ids.get('cpu family', '?')} model {ids.get('model', '?')}")
    return f"{info['model']} ({', '.join(detail)})"


def fma_peak_gflops(threads: int) -> float:
    """The FMA peak measured now on ``threads`` threads (independent FMA chains, GFLOP/s)."""
    return float(_core.fma_peak_gflops(threads))


def machine_header(threads: int, peak: float | None = None) -> tuple[str, float]:
    """The lines naming the CPU, its caches and ISA flags, mipnet's kernel path and GEMM plan and the FMA
    peak, and the peak on ``threads`` threads that shares of the peak refer to: measured now unless
    ``peak`` is given."""
    info = _core.cpu_info()
    _, flags = _cpuinfo_fields()
    one = fma_peak_gflops(1)
    many = fma_peak_gflops(threads) if threads > 1 else one
    used = many if peak is None else peak
    isa_flags = [f for f in ("avx512f", "avx512_bf16", "amx_tile", "avx2", "fma") if f in flags]
    lines = [
        f"CPU: {cpu_name()}, {os.cpu_count()} logical cores; L1d {info['l1d'] >> 10} KiB, "
        f"L2 {info['l2'] >> 10} KiB ({info['cache_source']})",
        f"ISA: {' '.join(isa_flags) or 'baseline'}; mipnet kernels {info['isa']} (supported: "
        f"{', '.join(info['isa_supported'])}); GEMM plan {info['plan']}",
        f"FMA peak measured: {one:.0f} GFLOP/s on 1 core, {many:.0f} on {threads} threads"
        + ("" if peak is None else f"; shares of the peak use {peak:g}"),
    ]
    return "\n".join(lines), used


def peak_drift_line(start: float, end: float) -> str:
    """The FMA peak measured again after a run, beside the one before it; flagged when they differ by more
    than :data:`PEAK_DRIFT` (a shared VM whose speed changed during the run: figures measured in different
    phases do not compare, rounds taken in turns still do)."""
    line = f"FMA peak at the start {start:.0f}, at the end {end:.0f} GFLOP/s"
    if abs(end - start) > PEAK_DRIFT * max(start, end):
        line += (f": the machine's speed changed by more than {PEAK_DRIFT:.0%} during the run; compare engines "
                 "within a row (they take turns), not rows measured at different times")
    return line
