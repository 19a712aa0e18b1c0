"""Throughput of ``mipnet infer --ray`` with 1 and 2 local actors, the gradient exchange of ``mipnet train --ray``,
and the projection to a cluster of docs/distributed.md.

    python scripts/ray_scale.py [--size 384 512] [--pairs 16] [--iters 6 6] [--crop 256 320] [--batch-size 2]
                                [--train-iters 6 6] [--steps 4] [--nodes 16] [--bandwidth 10]
                                [--json ray_scale.json] [--md ray_scale.md]

On this machine, in one run: the per-pair time of one process without Ray (read, network, write of
``mipnet.inference.infer_pair``, all cores); ``mipnet.distributed.infer_dataset`` over ``--pairs`` generated pairs
with 1 actor (all cores) and 2 actors (half the cores each) on a local Ray cluster; the step time of one-process
training with ``--batch-size`` pairs; and 2 Ray workers sharing that batch, whose steps time the exchange of the
weights and gradients (broadcast + wait - compute + reduce, :class:`mipnet.distributed.RayGradients`). Then the
projection to ``--nodes`` nodes over a network of ``--bandwidth`` Gbit/s (formulas in docs/distributed.md).
Prints the machine header first, as every timing of the project does (CONTRIBUTING.md); run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import mipnet
from mipnet.bench.machine import fma_peak_gflops, machine_header, peak_drift_line
from mipnet.data.synthetic import make_pair
from mipnet.distributed import RayGradients, infer_dataset, require_ray
from mipnet.inference.outputs import OutputOptions, OutputWriter, infer_pair
from mipnet.stereo import io
from mipnet.training import resolve_config
from mipnet.training.fit import fit


def write_pairs(folder: Path, count: int, size: tuple[int, int]) -> tuple[str, str]:
    """``count`` generated pairs of ``size`` as L/pNNN.png, R/pNNN.png; the two globs."""
    for side in "LR":
        (folder / side).mkdir(parents=True)
    for i in range(count):
        pair = make_pair(*size, seed=i)
        io.write_image(folder / "L" / f"p{i:03d}.png", pair["left"])
        io.write_image(folder / "R" / f"p{i:03d}.png", pair["right"])
    return str(folder / "L" / "*.png"), str(folder / "R" / "*.png")


def one_process_pairs(left: str, right: str, out: Path, iters: tuple[int, int], threads: int) -> list[float]:
    """Seconds per pair of ``infer_pair`` in this process on ``threads`` threads, the first pair (warm-up) left out."""
    from mipnet.inference.pairs import resolve_pairs

    mipnet.set_num_threads(threads)
    model = mipnet.MIPNet.pretrained()
    write = OutputWriter(OutputOptions(), out, None)
    out.mkdir(parents=True)
    seconds = []
    for lp, rp, name in resolve_pairs(left, right):
        start = time.perf_counter()
        infer_pair(model, lp, rp, name, write, iters, 20, 1.0)
        seconds.append(time.perf_counter() - start)
    return seconds[1:]


def training_steps(ray, run: Path, args, workers: int) -> tuple[list[float], list[dict]]:
    """Step seconds (the first left out) of ``args.steps`` steps, on this process (``workers`` 0) or on Ray
    workers; with workers, the exchange timings of :class:`RayGradients` too."""
    config = resolve_config("cpu", overrides=dict(crop=tuple(args.crop), batch_size=args.batch_size,
                                                  iters=tuple(args.train_iters), steps=args.steps, val_every=0,
                                                  workers=0, checkpoint_every=args.steps, freeze_bn=True,
                                                  data=["scenes:0.5", "synthetic-underwater:0.5"]))
    if not workers:
        records = fit(config, str(run), progress=False)
        return [r["seconds"] for r in records[1:]], []
    gradients = RayGradients(ray, workers)
    try:
        records = fit(config, str(run), progress=False, gradients=gradients)
    finally:
        gradients.close()
    return [r["seconds"] for r in records[1:]], gradients.timings[1:]


def exchange_seconds(timing: dict) -> float:
    """The part of a step spent moving weights and gradients and summing them."""
    return timing["broadcast"] + timing["wait"] - timing["compute"] + timing["reduce"]


def projection(results: dict, nodes: int, bandwidth_gbit: float) -> dict:
    """docs/distributed.md: inference at n e / t_pair pairs/s (e: Ray's steady-state share of one process's
    rate); a data-parallel step t(n) = t_1 + t_x(n) with
    t_x(n) = t_local + 2 n S / BW + (n - 2) t_add."""
    infer = results["infer"]
    e = infer["ray_1_actor"]["pairs_per_s"] / infer["one_process"]["pairs_per_s"]
    pairs_per_s = nodes * e / infer["one_process"]["s_per_pair"]
    train = results["train"]
    size_bytes, bandwidth = train["gradient_bytes"], bandwidth_gbit * 1e9 / 8
    t_add = train["reduce_s"]  # 2 workers: one addition of a gradient set (and its copy)
    # the local exchange of 2 workers, the weights out to and the gradients in from n nodes through the driver's
    # network link, and the n - 2 further additions
    t_x = train["exchange_s"] + 2 * nodes * size_bytes / bandwidth + (nodes - 2) * t_add
    t_step = train["one_process_step_s"] + t_x
    return {"nodes": nodes, "bandwidth_gbit_s": bandwidth_gbit, "ray_efficiency": e, "infer_pairs_per_s": pairs_per_s,
            "infer_s_per_1e6_pairs": 1e6 / pairs_per_s, "train_exchange_s": t_x, "train_step_s": t_step,
            "train_pairs_per_s": nodes * train["batch_size"] / t_step,
            "train_speedup": nodes * train["one_process_step_s"] / t_step}


def markdown(results: dict) -> str:
    infer, train, proj = results["infer"], results["train"], results["projection"]
    h, w = results["size"]
    lines = [f"Inference, {results['pairs']} pairs of {h}x{w}, iters {results['iters']}:", "",
             "| run | pairs/s (steady) | s/pair (median, per actor) | start s | kernel threads |", "|---|---|---|---|---|"]
    for key, label in (("one_process", "1 process, no Ray"), ("ray_1_actor", "Ray, 1 actor"),
                       ("ray_2_actors", "Ray, 2 actors")):
        row = infer[key]
        start = f"{row['start_s']:.1f}" if "start_s" in row else "-"
        lines.append(f"| {label} | {row['pairs_per_s']:.3f} | {row['s_per_pair']:.2f} | {start} | {row['threads']} |")
    ch, cw = train["crop"]
    lines += ["", f"Training, batch {train['batch_size']} of {ch}x{cw}, iters {train['iters']}, "
                  f"{train['gradient_bytes'] / 1e6:.1f} MB of gradients:", "",
              "| run | s/step (median) | exchange s/step: broadcast + wait - compute + reduce |", "|---|---|---|",
              f"| 1 process | {train['one_process_step_s']:.2f} | - |",
              f"| Ray, 2 workers | {train['ray_2_workers_step_s']:.2f} | {train['exchange_s']:.3f} "
              f"({train['broadcast_s']:.3f} + {train['wait_s']:.3f} - {train['compute_s']:.3f} + "
              f"{train['reduce_s']:.3f}) |",
              "", f"Projection to {proj['nodes']} nodes at {proj['bandwidth_gbit_s']:g} Gbit/s: inference "
                  f"{proj['infer_pairs_per_s']:.2f} pairs/s ({proj['infer_s_per_1e6_pairs'] / 3600:.0f} h per "
                  f"10^6 pairs, Ray efficiency {proj['ray_efficiency']:.2f}); training {proj['train_step_s']:.2f} "
                  f"s/step with a global batch of {proj['nodes'] * train['batch_size']} (exchange "
                  f"{proj['train_exchange_s']:.2f} s), {proj['train_speedup']:.1f}x one node's pairs/s."]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"))
    ap.add_argument("--pairs", type=int, default=16)
    ap.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    ap.add_argument("--crop", type=int, nargs=2, default=(256, 320), metavar=("H", "W"))
    ap.add_argument("--batch-size", type=int, default=2)
    ap.add_argument("--train-iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--nodes", type=int, default=16)
    ap.add_argument("--bandwidth", type=float, default=10.0, help="network Gbit/s of the projection")
    ap.add_argument("--json", default="ray_scale.json")
    ap.add_argument("--md", default="ray_scale.md")
    a = ap.parse_args()
    cores = os.cpu_count() or 1
    header, peak = machine_header(cores)
    print(header, flush=True)
    ray = require_ray()
    ray.init(num_cpus=cores, include_dashboard=False, log_to_driver=False, logging_level="warning")
    iters = tuple(a.iters)
    results: dict = {"size": list(a.size), "pairs": a.pairs, "iters": list(iters), "cores": cores}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            left, right = write_pairs(root / "pairs", a.pairs, tuple(a.size))
            single = one_process_pairs(left, right, root / "one", iters, cores)
            infer = {"one_process": {"s_per_pair": statistics.median(single), "pairs_per_s": 1 / statistics.mean(single),
                                     "threads": cores}}
            for workers, key in ((1, "ray_1_actor"), (2, "ray_2_actors")):
                report = infer_dataset(left, right, root / key, workers=workers, iters=iters, progress=False)
                first, last = report.finished[0], report.finished[-1]
                # steady state: the pairs after the first over the time after it (the actors' start left out)
                infer[key] = {"s_per_pair": statistics.median(report.seconds), "pairs_per_s": (a.pairs - 1) / (last - first),
                              "start_s": first - report.seconds[0], "wall_s": last, "threads": sorted(set(report.threads))}
                print(key, infer[key], flush=True)
            results["infer"] = infer
            one_steps, _ = training_steps(ray, root / "train_one", a, 0)
            ray_steps, timings = training_steps(ray, root / "train_ray", a, 2)
            model = mipnet.MIPNet()
            results["train"] = {
                "crop": list(a.crop), "batch_size": a.batch_size, "iters": list(a.train_iters),
                "gradient_bytes": sum(p.data.nbytes for p in model.parameters()),
                "one_process_step_s": statistics.median(one_steps), "ray_2_workers_step_s": statistics.median(ray_steps),
                "exchange_s": statistics.median(exchange_seconds(t) for t in timings),
                **{f"{k}_s": statistics.median(t[k] for t in timings) for k in ("broadcast", "wait", "compute", "reduce")}}
            print("train", results["train"], flush=True)
    finally:
        ray.shutdown()
    results["projection"] = projection(results, a.nodes, a.bandwidth)
    results["header"] = header
    with open(a.json, "w") as f:
        json.dump(results, f, indent=2)
    text = markdown(results)
    with open(a.md, "w") as f:
        f.write(header + "\n\n" + text)
    print(text)
    print(peak_drift_line(peak, fma_peak_gflops(cores)))


if __name__ == "__main__":
    main()
