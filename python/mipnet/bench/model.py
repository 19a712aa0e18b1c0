"""Whole-model benchmark: every engine in one run, same weights, inputs, initial field and threads.

    python -m mipnet.bench model [--threads 2] [--sizes 384x512 768x1024 1088x1920]
                                 [--train 384x512x2:6,6 128x256x4:3,3] [--engines ...] [--rounds 3]
                                 [--precision fp32 bf16] [--profile]

Engines: ``mipnet``; ``torch`` (eager, the reference model of tests_py/reference); ``openvino`` (fp32
hint) and ``onnxruntime`` (CPU), both running mipnet's own ONNX export of the same weights
(``mipnet.export_onnx``, opset 17, fixed size, with the ``disp_init`` input so that every engine starts
from the same field; docs/deployment.md). OpenVINO and onnxruntime are bench extras
(``pip install ".[bench]"``); an engine that is not installed is listed as such. The weights are the
torch reference's initialisation (seed 0) when torch is among the engines, else mipnet's own (seed 0),
so that ``--engines mipnet onnxruntime openvino`` runs without torch and outside the source tree. Eval rows time the forward pass (6+6 iterations) after one untimed run;
train rows time one step (forward, sequence loss, backward, AdamW) for mipnet and torch. Each
measurement runs in a fresh subprocess that imports only its own engine (mipnet reads the reference's
initial weights from a file), so its peak resident memory (ru_maxrss) is that engine's alone.
Before any time is printed, the disparities of every engine are checked against mipnet's (at most
1e-3 px apart) and the training losses of mipnet and torch against each other (1e-2 relative).
``--precision fp32 bf16`` adds the row ``mipnet bf16`` to each eval case: mipnet under
``mipnet.autocast(dtype="bfloat16")`` (float32 with a warning on a CPU without bf16 dot products), checked
against mipnet's float32 disparity by its mean difference (at most 0.1 px) rather than by the 1e-3 px of the
float32 engines. ``--rounds N`` runs every case N times with the engines taking turns and prints the median with its
range (a shared VM's speed drifts by tens of percent within minutes). ``--profile`` adds mipnet's
profiler table (``mipnet.profiler``) for the first eval size and the first
train case.
"""

from __future__ import annotations

import json
import statistics
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Callable, Sequence

from .machine import fma_peak_gflops, machine_header, peak_drift_line

REFERENCE_HINT = "run from the repository root (the torch reference lives in tests_py/reference)"
ENGINES = ("mipnet", "torch", "openvino", "onnxruntime")
#: Largest disparity difference between engines before times are printed (px).
AGREEMENT_PX = 1e-3
#: Largest mean disparity difference of mipnet in bfloat16 from mipnet in float32 (px).
AGREEMENT_BF16_MEAN_PX = 0.1
#: The row of mipnet under ``mipnet.autocast(dtype="bfloat16")`` (``--precision bf16``).
BF16 = "mipnet bf16"
#: Largest relative difference of the training losses of mipnet and torch. Looser than eval: in
#: training mode the iAFF BatchNorms normalise 2N samples of globally pooled features, which for
#: small batches of similar images amplifies float32 rounding.
AGREEMENT_LOSS = 1e-2


def reference_dir() -> Path | None:
    """tests_py/ of the source tree holding the torch reference, if reachable."""
    for base in (Path.cwd(), Path(__file__).resolve().parents[3]):
        if (base / "tests_py" / "reference" / "mipnet_torch.py").is_file():
            return base / "tests_py"
    return None


# Runs in the child process: builds the engine from one seeded torch init, times `runs` calls after
# `warmup` untimed ones, writes the output (eval disparity or train loss) to `out`.
_CHILD = r"""
import json, resource, sys, time
import numpy as np
a = json.loads(sys.argv[1])
n, h, w, iters = a["n"], a["h"], a["w"], tuple(a["iters"])
rng = np.random.default_rng(0)
left = rng.uniform(0, 255, (n, 3, h, w)).astype(np.float32)
right = np.roll(left, -4, axis=3)
d0 = rng.uniform(0.5, 3.0, (n, 1, h // 16, w // 16)).astype(np.float32)
gt = np.full((n, 1, h, w), 4.0, np.float32)
engine, mode = a["engine"], a["mode"]
profile = None
if engine.startswith("mipnet"):
    # the reference's initial weights, from the file the parent wrote (torch is not imported here)
    import mipnet
    mipnet.set_num_threads(a["threads"])
    model = mipnet.MIPNet()
    with np.load(a["weights"]) as f:
        model.load_state_dict({k: f[k] for k in f.files})
    if mode == "eval":
        model.eval()
        bf16 = mipnet.autocast(dtype="bfloat16", enabled=engine == "mipnet bf16")
        def run():
            with bf16:
                return model(left, right, iters=iters, disp_init=d0)
    else:
        model.train()
        opt = mipnet.optim.AdamW(model.parameters(), lr=1e-4, weight_decay=1e-5)
        def run():
            opt.zero_grad()
            loss = mipnet.model.losses.sequence_loss(model(left, right, iters=iters, disp_init=d0), gt, gt > 0)
            loss.backward()
            with mipnet.profiler.record("AdamW.step"):
                opt.step()
            return np.asarray(loss.item())
elif engine == "torch":
    import torch
    torch.set_num_threads(a["threads"])
    sys.path.insert(0, a["ref_dir"])
    from reference import MIPNetTorch, sequence_loss_torch
    torch.manual_seed(0)
    ref = MIPNetTorch()
    if mode == "eval":
        ref.eval()
        def run():
            with torch.no_grad():
                return ref(torch.from_numpy(left), torch.from_numpy(right), iters=iters, disp_init=torch.from_numpy(d0))[:, 0].numpy()
    else:
        ref.train()
        opt = torch.optim.AdamW(ref.parameters(), lr=1e-4, weight_decay=1e-5)
        def run():
            opt.zero_grad()
            preds = ref(torch.from_numpy(left), torch.from_numpy(right), iters=iters, disp_init=torch.from_numpy(d0))
            loss = sequence_loss_torch(preds, torch.from_numpy(gt), torch.from_numpy(gt > 0))
            loss.backward()
            opt.step()
            return np.asarray(loss.item())
else:
    feeds = {"left": left, "right": right, "disp_init": d0}
    if engine == "openvino":
        import openvino as ov
        compiled = ov.Core().compile_model(a["onnx"], "CPU", {"INFERENCE_NUM_THREADS": a["threads"],
                                                               "INFERENCE_PRECISION_HINT": "f32"})
        run = lambda: np.asarray(compiled(feeds)[0])[:, 0]
    else:
        import onnxruntime as ort
        so = ort.SessionOptions()
        so.intra_op_num_threads, so.inter_op_num_threads = a["threads"], 1
        sess = ort.InferenceSession(a["onnx"], so, providers=["CPUExecutionProvider"])
        run = lambda: sess.run(None, feeds)[0][:, 0]
for _ in range(a["warmup"]):
    run()
seconds = []
if a["profile"]:
    with mipnet.profiler.profile() as profile:
        out = run()
else:
    for _ in range(a["runs"]):
        t0 = time.perf_counter(); out = run(); seconds.append(time.perf_counter() - t0)
np.save(a["out"], np.asarray(out))
print(json.dumps({"seconds": seconds, "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "table": profile.table() + "\n\n" + profile.scope_table() if profile is not None else None}))
"""

# Writes the torch reference's initial weights (seed 0) for the mipnet children.
_WEIGHTS = r"""
import json, sys
import numpy as np
import torch
a = json.loads(sys.argv[1])
sys.path.insert(0, a["ref_dir"])
from reference import MIPNetTorch
torch.manual_seed(0)
np.savez(a["weights"], **{k: v.numpy() for k, v in MIPNetTorch().state_dict().items()})
"""

# Without torch: mipnet's own initial weights (seed 0), in the same file format.
_WEIGHTS_MIPNET = r"""
import json, sys
import numpy as np
import mipnet
a = json.loads(sys.argv[1])
mipnet.manual_seed(0)
np.savez(a["weights"], **mipnet.MIPNet().state_dict())
"""

# Exports mipnet's eval forward with the bench weights (fixed size, iterations unrolled, disp_init an input) to
# ONNX, opset 17, with mipnet.export_onnx (docs/deployment.md).
_EXPORT = r"""
import json, sys
import numpy as np
import mipnet
a = json.loads(sys.argv[1])
model = mipnet.MIPNet()
with np.load(a["weights"]) as f:
    model.load_state_dict({k: f[k] for k in f.files})
mipnet.export_onnx(model.eval(), a["onnx"], size=(a["h"], a["w"]), batch=a["n"], iters=tuple(a["iters"]),
                   disp_init_input=True)
"""


def _child(script: str, args: dict, threads: int) -> dict:
    env = {**os.environ, "MIPNET_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads), "MIPNET_PROFILE": ""}
    out = subprocess.run([sys.executable, "-c", script, json.dumps(args)], capture_output=True, text=True, env=env)
    if out.returncode != 0:
        lines = [ln for ln in out.stderr.strip().splitlines() if ln.strip()]
        return {"error": lines[-1] if lines else f"exit status {out.returncode}"}
    return json.loads(out.stdout.strip().splitlines()[-1]) if script is _CHILD else {}


def _installed(engine: str) -> bool:
    import importlib.util

    module = {"mipnet": "mipnet", BF16: "mipnet", "torch": "torch", "openvino": "openvino", "onnxruntime": "onnxruntime"}[engine]
    return importlib.util.find_spec(module) is not None and (engine in ("mipnet", "torch") or importlib.util.find_spec("onnx") is not None)


def _parse_train(spec: str) -> tuple[int, int, int, tuple[int, int]]:
    """"384x512x2:6,6" -> (h, w, batch, iters)."""
    size, _, it = spec.partition(":")
    h, w, n = (int(v) for v in size.lower().split("x"))
    return h, w, n, tuple(int(v) for v in (it or "6,6").split(","))  # type: ignore[return-value]


def run(threads: int, sizes: Sequence[tuple[int, int]], train: Sequence[str], engines: Sequence[str] = ENGINES,
        profile: bool = False, warmup: int = 1, rounds: int = 1, precisions: Sequence[str] = ("fp32",)) -> int:
    """Prints the header, the agreement check and the table; returns the exit status.

    Each case runs every engine ``rounds`` times, a fresh process each, the engines taking turns
    (mipnet, torch, ..., mipnet, torch, ...), so that a machine whose speed drifts (a shared VM)
    slows every engine alike; the table gives the median seconds and, with several rounds, the
    range."""
    ref_dir = reference_dir()
    if ref_dir is None and "torch" in engines:
        print(f"mipnet.bench model: no torch reference found: {REFERENCE_HINT}", file=sys.stderr)
        return 1
    missing = [e for e in engines if not _installed(e)]
    engines = [e for e in engines if e not in missing]
    header, peak_start = machine_header(threads)
    print(header)
    print(f"MIPNet 6+6 iterations (train rows: as given), {threads} threads everywhere, same weights, inputs and "
          f"initial field; peak = max RSS of a fresh process; seconds of one call after {warmup} untimed"
          + (f", median of {rounds} rounds (engines taking turns)" if rounds > 1 else ""))
    if missing:
        print(f"not installed (pip install \".[bench]\"): {', '.join(missing)}")
    rows, status = [], 0
    with tempfile.TemporaryDirectory(prefix="mipnet-bench-") as tmp:
        base = {"ref_dir": str(ref_dir or ""), "threads": threads, "warmup": warmup, "runs": 1, "profile": False,
                "weights": os.path.join(tmp, "weights.npz")}
        err = _child(_WEIGHTS if "torch" in engines else _WEIGHTS_MIPNET, base, threads).get("error")
        if err:
            print(f"mipnet.bench model: could not build the reference weights: {err}", file=sys.stderr)
            return 1
        for h, w in sizes:
            case = {**base, "mode": "eval", "n": 1, "h": h, "w": w, "iters": [6, 6]}
            onnx = os.path.join(tmp, f"mipnet_{h}x{w}.onnx")
            if {"openvino", "onnxruntime"} & set(engines):
                err = _child(_EXPORT, {**case, "onnx": onnx}, threads).get("error")
                if err:
                    print(f"mipnet.export_onnx at {h}x{w} failed: {err}", file=sys.stderr)
            evaluated = list(engines) + ([BF16] if "bf16" in precisions and "mipnet" in engines else [])
            outs = {e: os.path.join(tmp, f"{e.replace(' ', '_')}_{h}x{w}.npy") for e in evaluated}
            results = _rounds(rounds, evaluated, lambda e: {**case, "engine": e, "onnx": onnx, "out": outs[e]},
                              threads, f"eval {h}x{w}")
            status |= _agree(f"eval {h}x{w}", results, outs, "px")
            rows.append((f"eval {h}x{w}", h * w / 1e6, results))
        for spec in train:
            h, w, n, iters = _parse_train(spec)
            case = {**base, "mode": "train", "n": n, "h": h, "w": w, "iters": list(iters)}
            trainers = [e for e in engines if e in ("mipnet", "torch")]
            outs = {e: os.path.join(tmp, f"{e}_train_{spec.replace(':', '_')}.npy") for e in trainers}
            results = _rounds(rounds, trainers, lambda e: {**case, "engine": e, "out": outs[e]}, threads, f"train {spec}")
            status |= _agree(f"train {spec}", results, outs, "rel")
            rows.append((f"train {h}x{w} b{n} it{iters[0]},{iters[1]}", None, results))
        if status:
            print("engines disagree (see above): no times printed")
            return status
        print(_table(rows))
        print(peak_drift_line(peak_start, fma_peak_gflops(threads)))
        if profile:
            _profiles(base, sizes, train, threads, tmp)
    return 0


def _rounds(rounds: int, engines: Sequence[str], args_of: Callable[[str], dict], threads: int, name: str) -> dict:
    """Each engine's result over ``rounds`` turns: its seconds of every round, its largest peak, and
    the first error if any round failed (later rounds overwrite the output file with the same
    values: same inputs and weights)."""
    results: dict = {e: {"seconds": [], "peak_mib": 0.0} for e in engines}
    for k in range(rounds):
        for e in engines:
            if "error" in results[e]:
                continue
            r = _child(_CHILD, args_of(e), threads)
            if "error" in r:
                results[e] = r
            else:
                results[e]["seconds"] += r["seconds"]
                results[e]["peak_mib"] = max(results[e]["peak_mib"], r["peak_mib"])
            print(f"  done: {name} {e} (round {k + 1} of {rounds})", file=sys.stderr, flush=True)
    return results


def _agree(name: str, results: dict, outs: dict, kind: str) -> int:
    """Checks every engine's output against mipnet's; prints the worst difference."""
    import numpy as np

    ok = {e: r for e, r in results.items() if "error" not in r}
    for e, r in results.items():
        if "error" in r:
            print(f"{name}: {e} failed: {r['error']}")
    if "mipnet" not in ok:
        return 1
    ours = np.load(outs["mipnet"]).astype(np.float64)
    diffs = []
    for e in ok:
        if e == "mipnet":
            continue
        theirs = np.load(outs[e]).astype(np.float64)
        if theirs.shape != ours.shape:
            print(f"{name}: {e} output shape {theirs.shape} vs mipnet {ours.shape}")
            return 1
        if e == BF16:
            mean = float(np.abs(theirs - ours).mean())
            print(f"{name}: {BF16} against mipnet float32: mean |difference| {mean:.3f} px, max "
                  f"{float(np.abs(theirs - ours).max()):.2f} px")
            if mean > AGREEMENT_BF16_MEAN_PX:
                return 1
            continue
        d = float(np.abs(theirs - ours).max())
        d = d / max(float(np.abs(ours).max()), 1e-30) if kind == "rel" else d
        diffs.append(f"{e} {d:.1e}")
        if d > (AGREEMENT_PX if kind == "px" else AGREEMENT_LOSS):
            print(f"{name}: {e} differs from mipnet by {d:.2e} {kind}")
            return 1
    print(f"{name}: agree with mipnet, max |difference| ({kind}): {', '.join(diffs) or 'no other engine'}")
    return 0


def _table(rows: list) -> str:
    head = (f"{'case':<26} {'engine':<12} {'seconds':>8} {'range':>13} {'s/MP':>7} {'peak MiB':>9} "
            f"{'engine/mipnet':>14}")
    lines = [head, "-" * len(head)]
    for name, mp, results in rows:
        ours = statistics.median(results["mipnet"]["seconds"])
        for e, r in results.items():
            if "error" in r:
                continue
            s = statistics.median(r["seconds"])
            spread = f"{min(r['seconds']):.2f}-{max(r['seconds']):.2f}" if len(r["seconds"]) > 1 else ""
            per_mp = f"{s / mp:.2f}" if mp else ""
            ratio = "" if e == "mipnet" else f"{s / ours:.2f}x"
            lines.append(f"{name:<26} {e:<12} {s:>8.2f} {spread:>13} {per_mp:>7} {r['peak_mib']:>9.0f} {ratio:>14}")
    lines.append("engine/mipnet: the engine's seconds over mipnet's (above 1: mipnet is faster)")
    return "\n".join(lines)


def _profiles(base: dict, sizes, train, threads: int, tmp: str) -> None:
    cases = []
    if sizes:
        h, w = sizes[0]
        cases.append((f"eval {h}x{w}", {**base, "mode": "eval", "n": 1, "h": h, "w": w, "iters": [6, 6]}))
    if train:
        h, w, n, iters = _parse_train(train[0])
        cases.append((f"train step {train[0]}", {**base, "mode": "train", "n": n, "h": h, "w": w, "iters": list(iters)}))
    for name, case in cases:
        r = _child(_CHILD, {**case, "engine": "mipnet", "profile": True, "out": os.path.join(tmp, "profile.npy")}, threads)
        print(f"\nmipnet profile, {name} (after {base['warmup']} untimed run):")
        print(r.get("table") or f"failed: {r.get('error')}")
