"""``mipnet info``: the configuration, parameter counts per module, thread count, what the weights were
trained on, and (``--size H W``) memory estimates.

    mipnet info
    mipnet info --weights run/model.safetensors --history
    mipnet info --size 384 512 --batch 2 --measure
"""

from __future__ import annotations

import argparse

from ..errors import ArgumentError
from .common import ImageSize, add_iters, load_model, positive_int


def add_parser(sub) -> argparse.ArgumentParser:
    """Registers ``info`` on the ``mipnet`` sub-command parsers."""
    p = sub.add_parser("info", help="config, parameter counts per module, thread count, memory estimates",
                       description="What the model is: its config, parameter counts, threads, what its weights "
                                   "were trained on, and with --size the memory a pass needs.")
    p.add_argument("--weights", metavar="FILE", help="weights file to describe (default: the shipped weights)")
    p.add_argument("--history", action="store_true",
                   help="print every training run of the weights' lineage and every command, not only the newest")
    p.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), action=ImageSize,
                   help="also print the peak memory of an eval forward and a training step at this image size")
    p.add_argument("--batch", type=positive_int, default=1, help="image pairs per pass for --size (default 1)")
    add_iters(p)
    p.add_argument("--measure", action="store_true",
                   help="with --size: also run each pass in a fresh process and print its measured peak memory")
    p.set_defaults(func=run)
    return p


def describe_weights(weights: str | None, history: bool = False) -> list[str]:
    """Lines saying what a weights file (default: the shipped one) was trained on: how it was made and its last
    run's recipe, its steps and validation table; ``history``: every run of its lineage and every command."""
    from ..model import pretrained
    from ..serialization import load_safetensors

    if weights:
        meta, label = pretrained.decode_metadata(load_safetensors(weights)[1]), weights
    elif pretrained.available():
        meta, label = pretrained.pretrained_info(), f"shipped ({pretrained.PRETRAINED_PATH.name})"
    else:
        return ["weights: none shipped (untrained network)"]
    lines = [f"weights: {label}"]
    trained, commands, validation = meta.get("trained"), meta.get("commands"), meta.get("validation")
    # A mean of weights describes each file it averages after "; the last: ", and each run after "; then ":
    # the first clause says how this file was made, the last "then" clause is the newest run's recipe.
    nested = isinstance(trained, str) and "; the last: " in trained
    if nested and not history:
        last_run = trained.rsplit("; then ", 1)[-1]
        lines.append(f"  trained: {trained.partition('; the last: ')[0]}; the newest run: {last_run}")
    elif trained is not None:
        lines.append(f"  trained: {trained}")
    lines += [f"  {key}: {meta[key]}" for key in ("step", "generator_version", "mipnet_version") if key in meta]
    if isinstance(commands, list) and commands and not history:
        lines.append(f"  commands: {len(commands)}, the last: {commands[-1]}")
    elif isinstance(commands, list):
        lines += ["  commands:"] + [f"    {command}" for command in commands]
    elif commands is not None:
        lines.append(f"  commands: {commands}")
    rows = {}
    if isinstance(validation, dict):
        rows = {name: row for name, row in validation.items() if isinstance(row, dict) and {"epe", "bad3"} <= set(row)}
    if rows:
        width = max(map(len, rows))
        lines.append("  validation (EPE px / bad-3 %):")
        lines += [f"    {name:<{width}}  {row['epe']:.3f} / {row['bad3']:.1f}" for name, row in rows.items()]
    elif validation is not None:
        lines.append(f"  validation: {validation}")
    if not history and (nested or (isinstance(commands, list) and len(commands) > 1)):
        lines.append("  (mipnet info --history: every run of the lineage and every command)")
    return lines


def run(args: argparse.Namespace) -> int:
    import mipnet

    if args.measure and not args.size:
        raise ArgumentError("--measure needs --size H W")
    model = load_model(args.weights, quiet=True)
    print(f"mipnet {mipnet.__version__}  threads={mipnet.get_num_threads()}  dtype={model.dtype}")
    print("\n".join(describe_weights(args.weights, args.history)))
    print("config: " + ", ".join(f"{k}={v}" for k, v in vars(model.config).items()))
    counts: dict[str, int] = {}
    for name, p in model.named_parameters():
        parts = name.split(".")
        key = "encoder.fuse (iAFF)" if ".fuse." in name else ".".join(parts[:2])
        counts[key] = counts.get(key, 0) + p.data.size
    width = max(map(len, counts))
    print("parameters:")
    for key, n in counts.items():
        print(f"  {key:<{width}}  {n:>10,}")
    print(f"  {'total':<{width}}  {model.num_parameters():>10,}")
    if args.size:
        from ..model import memory

        room = memory.available_memory()
        print("memory (estimated" + (f"; available now {memory.format_bytes(room[0])}, {room[1]}):" if room else "):"))
        for mode in ("eval", "train"):
            needed = memory.estimate(*args.size, args.batch, mode, args.iters, model)
            line = "  " + needed.describe()
            if args.measure and room and needed.activations > room[0]:
                line += "; not measured: more than is available"
            elif args.measure:
                measured = memory.measure_peak(*args.size, args.batch, mode, args.iters)
                line += (f"; measured {memory.format_bytes(measured)} ({100 * (needed.total / measured - 1):+.0f}%, "
                         "fresh process, default float32 model)")
            print(line, flush=True)
    return 0
