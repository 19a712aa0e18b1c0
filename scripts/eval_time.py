"""Times consecutive eval forwards of one fresh process: seconds, page faults, CPU time and peak RSS per run.

    python scripts/eval_time.py [--size 384 512] [--runs 7] [--precision fp32|bf16] [--profile]

The same forward as `python -m mipnet.bench model --sizes HxW` (random weights, an image and its copy shifted by 4
pixels, 6+6 iterations) for comparing two builds of the engine in one window of this VM, alternating runs: put the
other build first on the path (`PYTHONPATH=/path/to/other/python python scripts/eval_time.py`). The first runs pay
for faulting in the allocator's cache and for filling the kernel cache; compare the later ones. `--profile` prints
`mipnet.profiler`'s table of the last run (time per op family).
"""

from __future__ import annotations

import argparse
import contextlib
import resource
import time

import numpy as np

import mipnet
from mipnet.bench.machine import fma_peak_gflops, machine_header, peak_drift_line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--precision", choices=("fp32", "bf16"), default="fp32",
                    help="bf16: the forwards run under mipnet.autocast(dtype='bfloat16')")
    ap.add_argument("--profile", action="store_true", help="print mipnet.profiler's table of the last run")
    a = ap.parse_args()
    (h, w) = a.size
    mipnet.set_num_threads(a.threads)
    header, peak = machine_header(a.threads)
    print(header)
    rng = np.random.default_rng(0)
    left = rng.uniform(0, 255, (h, w, 3)).astype(np.float32)
    right = np.roll(left, -4, axis=1)
    model = mipnet.MIPNet()
    model.eval()
    print(f"mipnet from {mipnet.__file__}; eval {h}x{w}, {a.precision}, {a.threads} threads")
    profile = None
    for run in range(a.runs):
        last = a.profile and run == a.runs - 1
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        with mipnet.autocast(dtype="bfloat16", enabled=a.precision == "bf16"), \
                (mipnet.profiler.profile() if last else contextlib.nullcontext()) as profile:
            model(left, right)
        seconds, r1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF)
        print(f"run {run}: {seconds:.3f} s  faults {r1.ru_minflt - r0.ru_minflt}  user {r1.ru_utime - r0.ru_utime:.2f} s"
              f"  sys {r1.ru_stime - r0.ru_stime:.2f} s  peak {r1.ru_maxrss >> 10} MiB", flush=True)
    print(peak_drift_line(peak, fma_peak_gflops(a.threads)))
    if profile is not None:
        print(profile.table())


if __name__ == "__main__":
    main()
