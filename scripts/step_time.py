"""Times consecutive training steps of one fresh process: seconds, page faults, CPU time and peak RSS per step.

    python scripts/step_time.py [--size 128 256] [--batch 4] [--iters 3 3] [--steps 5] [--profile]

The same step as `python -m mipnet.bench model --train HxWxB:N16,N4` (random images, a constant ground truth, AdamW)
for comparing two builds of the engine in one window of this VM, alternating runs: put the other build first on
the path (`PYTHONPATH=/path/to/other/python python scripts/step_time.py`). The first step pays for faulting in
the allocator's cache; compare the later ones. `--profile` prints `mipnet.profiler`'s table of the last step (by op
family, then by scope).
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
    ap.add_argument("--size", type=int, nargs=2, default=(128, 256), metavar=("H", "W"))
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--iters", type=int, nargs=2, default=(3, 3), metavar=("N16", "N4"))
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--profile", action="store_true", help="print the profile of the last step")
    a = ap.parse_args()
    (h, w), n = a.size, a.batch
    mipnet.set_num_threads(a.threads)
    header, peak = machine_header(a.threads)
    print(header)
    rng = np.random.default_rng(0)
    left = rng.uniform(0, 255, (n, 3, h, w)).astype(np.float32)
    right = np.roll(left, -4, axis=3)
    d0 = rng.uniform(0.5, 3.0, (n, 1, h // 16, w // 16)).astype(np.float32)
    gt = np.full((n, 1, h, w), 4.0, np.float32)
    model = mipnet.MIPNet()
    model.train()
    opt = mipnet.optim.AdamW(model.parameters(), lr=1e-4, weight_decay=1e-5)
    print(f"mipnet from {mipnet.__file__}; train {h}x{w}, batch {n}, iters {tuple(a.iters)}, {a.threads} threads")
    for step in range(a.steps):
        profiling = a.profile and step == a.steps - 1
        r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        with mipnet.profiler.profile() if profiling else contextlib.nullcontext() as prof:
            opt.zero_grad()
            loss = mipnet.model.losses.sequence_loss(model(left, right, iters=tuple(a.iters), disp_init=d0), gt, gt > 0)
            loss.backward()
            opt.step()
        seconds, r1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF)
        print(f"step {step}: {seconds:.2f} s  faults {r1.ru_minflt - r0.ru_minflt}  user {r1.ru_utime - r0.ru_utime:.2f} s"
              f"  sys {r1.ru_stime - r0.ru_stime:.2f} s  peak {r1.ru_maxrss >> 10} MiB", flush=True)
        if profiling:
            print(prof.table(), prof.scope_table(), sep="\n")
    print(peak_drift_line(peak, fma_peak_gflops(a.threads)))


if __name__ == "__main__":
    main()
