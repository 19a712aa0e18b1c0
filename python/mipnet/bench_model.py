"""Whole-model benchmark: mipnet vs the PyTorch reference (tests_py/reference), same weights, same
inputs, same thread count. Each measurement runs in a fresh subprocess, so its peak resident memory
(ru_maxrss) belongs to that run alone.

    python -m mipnet.bench model [--threads 2] [--sizes 384x512 1088x1920] [--train-size 384x512]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REFERENCE_HINT = "run from the repository root (the torch reference lives in tests_py/reference)"


def reference_dir() -> Path | None:
    """tests_py/ of the source tree holding the torch reference, if reachable."""
    for base in (Path.cwd(), Path(__file__).resolve().parents[2]):
        if (base / "tests_py" / "reference" / "mipnet_torch.py").is_file():
            return base / "tests_py"
    return None


# Runs in the child process: builds both models from one seeded torch init, times one call.
_CHILD = r"""
import json, resource, sys, time
import numpy as np
engine, mode, h, w, n, threads, ref_dir = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6]), sys.argv[7]
sys.path.insert(0, ref_dir)
import torch
torch.set_num_threads(threads)
from reference import MIPNetTorch, sequence_loss_torch
torch.manual_seed(0)
ref = MIPNetTorch()
rng = np.random.default_rng(0)
left = rng.uniform(0, 255, (n, 3, h, w)).astype(np.float32)
right = np.roll(left, -4, axis=3)
d0 = rng.uniform(0.5, 3.0, (n, 1, h // 16, w // 16))
gt = np.full((n, 1, h, w), 4.0, np.float32)
if engine == "mipnet":
    import mipnet
    mipnet.set_num_threads(threads)
    model = mipnet.MIPNet()
    model.load_state_dict({k: v.numpy() for k, v in ref.state_dict().items()})
    del ref
    def run():
        if mode == "eval":
            model.eval()(left, right, disp_init=d0)
        else:
            model.train()
            loss = mipnet.losses.sequence_loss(model(left, right, disp_init=d0), gt, gt > 0)
            loss.backward()
else:
    model = ref
    def run():
        if mode == "eval":
            with torch.no_grad():
                model.eval()(torch.from_numpy(left), torch.from_numpy(right), disp_init=torch.from_numpy(d0).float())
        else:
            model.train()
            preds = model(torch.from_numpy(left), torch.from_numpy(right), disp_init=torch.from_numpy(d0).float())
            sequence_loss_torch(preds, torch.from_numpy(gt), torch.from_numpy(gt > 0)).backward()
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter(); run(); seconds = time.perf_counter() - t0
print(json.dumps({"seconds": seconds, "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "base_mib": rss0 / 1024}))
"""


def measure(engine: str, mode: str, h: int, w: int, n: int, threads: int, ref_dir: Path) -> dict:
    env = {**os.environ, "MIPNET_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads)}
    out = subprocess.run([sys.executable, "-c", _CHILD, engine, mode, str(h), str(w), str(n), str(threads), str(ref_dir)],
                         capture_output=True, text=True, env=env)
    if out.returncode != 0:
        return {"error": (out.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(threads: int, sizes: list[tuple[int, int]], train_size: tuple[int, int], train_batch: int) -> str:
    ref_dir = reference_dir()
    if ref_dir is None:
        return f"mipnet.bench model: no torch reference found: {REFERENCE_HINT}"
    cases = [("eval forward", "eval", h, w, 1) for h, w in sizes]
    cases.append((f"train step (batch {train_batch})", "train", *train_size, train_batch))
    header = f"{'case':<24} {'size':>10} {'mipnet s':>9} {'torch s':>9} {'ratio':>6} {'mipnet MiB':>11} {'torch MiB':>10}"
    lines = [f"MIPNet, iters (6, 6), {threads} threads, same weights and inputs; peak = max RSS of the process", header,
             "-" * len(header)]
    for name, mode, h, w, n in cases:
        ours = measure("mipnet", mode, h, w, n, threads, ref_dir)
        theirs = measure("torch", mode, h, w, n, threads, ref_dir)
        if "error" in ours or "error" in theirs:
            lines.append(f"{name:<24} {h}x{w:<5} error: {ours.get('error') or theirs.get('error')}")
            continue
        lines.append(f"{name:<24} {f'{h}x{w}':>10} {ours['seconds']:>9.2f} {theirs['seconds']:>9.2f} "
                     f"{ours['seconds'] / theirs['seconds']:>6.2f} {ours['peak_mib']:>11.0f} {theirs['peak_mib']:>10.0f}")
        print(lines[-1], file=sys.stderr, flush=True)
    return "\n".join(lines)
