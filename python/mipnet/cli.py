"""The ``mipnet`` command line: ``info``, ``infer``, ``eval``, ``train``. Also ``python -m mipnet``."""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

ASSETS = Path(__file__).resolve().parent / "assets"
EXAMPLE_LEFT, EXAMPLE_RIGHT = ASSETS / "example_left.png", ASSETS / "example_right.png"
UNTRAINED_SEED = 0


def load_model(weights: str | None, quiet: bool = False):
    """The model to run: the weights file given, else the weights shipped with the package; an
    installation without them falls back to the untrained network (seeded) and says so."""
    import mipnet
    from . import pretrained

    if weights:
        return mipnet.load(weights).eval()
    if pretrained.available():
        return pretrained.load_pretrained()
    if not quiet:
        print("WARNING: this installation ships no trained MIPNet weights: this is the UNTRAINED network "
              f"(random initialisation, seed {UNTRAINED_SEED}); its disparities are not meaningful. "
              "Pass --weights FILE.safetensors to use trained weights.", file=sys.stderr)
    mipnet.manual_seed(UNTRAINED_SEED)
    return mipnet.MIPNet().eval()


def describe_weights(weights: str | None) -> list[str]:
    """Lines saying what a weights file (default: the shipped one) was trained on."""
    from . import pretrained
    from .weights import load_safetensors

    if weights:
        _, meta = load_safetensors(weights)
        label = weights
    elif pretrained.available():
        meta, label = pretrained.pretrained_info(), f"shipped ({pretrained.PRETRAINED_PATH.name})"
    else:
        return ["weights: none shipped (untrained network)"]
    lines = [f"weights: {label}"]
    for key in ("trained", "step", "generator_version", "mipnet_version", "commands"):
        if key in meta:
            lines.append(f"  {key}: {meta[key]}")
    if "validation" in meta:
        lines.append(f"  validation: {meta['validation']}")
    return lines


class Progress:
    """A progress bar on a terminal; one line per step otherwise (logs, CI)."""

    def __init__(self, total: int, label: str):
        self.total, self.label, self.done, self.start = total, label, 0, time.perf_counter()
        self.tty = sys.stderr.isatty()

    def step(self, name: str) -> None:
        self.done += 1
        elapsed = time.perf_counter() - self.start
        if self.tty:
            filled = int(30 * self.done / self.total)
            sys.stderr.write(f"\r{self.label} [{'#' * filled}{'.' * (30 - filled)}] {self.done}/{self.total} "
                             f"{elapsed:6.1f}s {name[:40]:<40}")
            if self.done == self.total:
                sys.stderr.write("\n")
        else:
            sys.stderr.write(f"{self.label} {self.done}/{self.total} {name} ({elapsed:.1f}s)\n")
        sys.stderr.flush()


def _expand(pattern: str) -> list[str]:
    paths = sorted(glob.glob(pattern)) if any(c in pattern for c in "*?[") else [pattern]
    missing = [p for p in paths if not os.path.isfile(p)]
    if not paths or missing:
        raise SystemExit(f"mipnet: no such file: {pattern if not paths else missing[0]}")
    return paths


def cmd_infer(args: argparse.Namespace) -> int:
    from . import geometry, io, viz

    if (args.left is None) != (args.right is None):
        raise SystemExit("mipnet infer: give both -l/--left and -r/--right, or neither (bundled example pair)")
    lefts = _expand(args.left) if args.left else [str(EXAMPLE_LEFT)]
    rights = _expand(args.right) if args.right else [str(EXAMPLE_RIGHT)]
    if len(lefts) != len(rights):
        raise SystemExit(f"mipnet infer: {len(lefts)} left images but {len(rights)} right images")
    calib = io.read_calib(args.calib) if args.calib else None
    model = load_model(args.weights)
    out = Path(args.output_directory)
    out.mkdir(parents=True, exist_ok=True)
    progress = Progress(len(lefts), "infer")
    for lp, rp in zip(lefts, rights):
        left, right = io.read_image(lp), io.read_image(rp)
        disp = model(left, right, iters=tuple(args.iters), seed=args.seed)
        stem = out / Path(lp).stem
        _write_npy(f"{stem}_disp.npy", disp)
        io.write_pfm(f"{stem}_disp.pfm", disp)
        io.write_image(f"{stem}_disp.png", viz.colorize(disp, vmin=args.vmin, vmax=args.vmax))
        if calib is not None:
            depth = geometry.disparity_to_depth(disp, calib)
            _write_npy(f"{stem}_depth.npy", depth)
            points, colors = geometry.depth_to_points(depth, calib, image=left)
            io.write_ply(f"{stem}_points.ply", points, colors)
        progress.step(Path(lp).name)
    print(f"wrote {len(lefts)} disparity map(s) to {out}/")
    return 0


def _write_npy(path: str, array: np.ndarray) -> None:
    from ._fileutil import atomic_write

    with atomic_write(path) as f:
        np.save(f, array)


def cmd_info(args: argparse.Namespace) -> int:
    import mipnet

    model = load_model(args.weights, quiet=True)
    print(f"mipnet {mipnet.__version__}  threads={mipnet.get_num_threads()}  dtype={model.dtype}")
    print("\n".join(describe_weights(args.weights)))
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
    return 0


DATASETS = ("synthetic", "synthetic-underwater", "scenes", "scenes-underwater", "motorcycle", "sceneflow", "middlebury2014", "middeval3", "eth3d",
            "kitti2012", "kitti2015", "crestereo")


def open_dataset(args: argparse.Namespace):
    """The evaluation pairs named by ``--dataset`` (``--root`` for the on-disk sets)."""
    from . import data

    if args.dataset in ("synthetic", "synthetic-underwater", "scenes", "scenes-underwater"):
        h, w = args.size
        underwater = args.dataset.endswith("-underwater")
        if underwater and args.preset is None:
            raise SystemExit(f"mipnet eval: --dataset {args.dataset} needs --preset (clear, coastal, turbid, low_light, random)")
        generator = data.SceneStereo if args.dataset.startswith("scenes") else data.SyntheticStereo
        return generator(args.n, h, w, seed=args.seed, underwater=args.preset if underwater else None)
    if args.dataset == "motorcycle":  # a real Middlebury pair bundled in scikit-image (evaluation only)
        return data.RealPairs("motorcycle", underwater=args.preset, seed=args.seed)
    if not args.root:
        raise SystemExit(f"mipnet eval: --dataset {args.dataset} needs --root DIR")
    make = {
        "sceneflow": lambda: data.SceneFlow(args.root, split="TEST"),
        "middlebury2014": lambda: data.Middlebury2014(args.root),
        "middeval3": lambda: data.MiddEval3(args.root, split="training", resolution=args.resolution),
        "eth3d": lambda: data.ETH3D(args.root, split="training"),
        "kitti2012": lambda: data.KITTI(args.root, year=2012),
        "kitti2015": lambda: data.KITTI(args.root, year=2015),
        "crestereo": lambda: data.CREStereo(args.root),
    }[args.dataset]
    return make()


def cmd_eval(args: argparse.Namespace) -> int:
    from . import pretrained
    from .evaluation import evaluate_method, format_table, result_row, sgbm_rows

    dataset = open_dataset(args)
    count = min(len(dataset), args.max_pairs) if args.max_pairs else len(dataset)
    pairs = lambda: (dataset[i] for i in range(count))  # noqa: E731 - one fresh pass per method
    methods = set(args.methods.split(","))
    rows = []
    if "mipnet" in methods:
        model = load_model(args.weights)
        progress = Progress(count, "mipnet")

        def predict(left, right):
            disp = model(left, right, iters=tuple(args.iters))
            progress.step("")
            return disp

        trained = bool(args.weights) or pretrained.available()
        rows.append(result_row("MIPNet" + ("" if trained else " (untrained)"), evaluate_method(pairs(), predict),
                               args.aggregation))
    if "sgbm" in methods:
        full, covered = sgbm_rows(pairs(), aggregation=args.aggregation)
        rows += [{**full, "method": "SGBM (full coverage)"}, {**covered, "method": "SGBM (covered)"}]
    name = args.dataset + (f" ({args.preset})" if args.preset else "")
    print(f"{name}: {count} pairs, {args.aggregation} over images; bad-x and d1 in percent, epe/a90/rms in px")
    print(format_table(rows))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mipnet", description="MIPNet stereo matching on the CPU (Rust engine).")
    p.add_argument("--threads", type=int, default=None, help="kernel threads (default: all cores / MIPNET_NUM_THREADS)")
    sub = p.add_subparsers(dest="command", required=True)

    inf = sub.add_parser("infer", help="disparity (and depth, point cloud) for stereo pairs")
    inf.add_argument("-l", "--left", help="left image or glob (default: the bundled example pair)")
    inf.add_argument("-r", "--right", help="right image or glob, same order as --left")
    inf.add_argument("-o", "--output_directory", "--output-directory", default="mipnet_out")
    inf.add_argument("--weights", help="weights file (.safetensors written by MIPNet.save)")
    inf.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    inf.add_argument("--calib", help="calib.txt (Middlebury/ETH3D) or K.txt: also write depth and a point cloud")
    inf.add_argument("--vmin", type=float, default=None, help="colour range (default: 1st-99th percentile)")
    inf.add_argument("--vmax", type=float, default=None)
    inf.add_argument("--seed", type=int, default=20, help="seed of the gamma initialisation (default 20)")
    inf.set_defaults(func=cmd_infer)

    info = sub.add_parser("info", help="config, parameter counts per module, thread count")
    info.add_argument("--weights", help="weights file to describe")
    info.set_defaults(func=cmd_info)

    ev = sub.add_parser("eval", help="metrics of MIPNet and OpenCV SGBM on a dataset")
    ev.add_argument("--dataset", required=True, choices=DATASETS)
    ev.add_argument("--root", help="dataset root folder (official layout)")
    ev.add_argument("--weights", help="weights file (.safetensors written by MIPNet.save)")
    ev.add_argument("--iters", type=int, nargs=2, default=(6, 6), metavar=("N16", "N4"))
    ev.add_argument("--methods", default="mipnet,sgbm", help="comma-separated: mipnet, sgbm")
    ev.add_argument("--preset", choices=("clear", "coastal", "turbid", "low_light", "random"),
                    help="underwater preset (random: water drawn around the presets per pair)")
    ev.add_argument("--n", type=int, default=50, help="number of generated pairs (synthetic sets)")
    ev.add_argument("--size", type=int, nargs=2, default=(384, 512), metavar=("H", "W"), help="generated pair size")
    ev.add_argument("--seed", type=int, default=1_000_000,
                    help="pair seed of the first generated pair (default 1000000: held out from training)")
    ev.add_argument("--resolution", default="H", choices=("F", "H", "Q"), help="MiddEval3 resolution")
    ev.add_argument("--max-pairs", type=int, default=None, help="evaluate only the first N pairs")
    ev.add_argument("--aggregation", default="mean", choices=("mean", "pooled"),
                    help="mean of per-image metrics (ETH3D) or pooled over all pixels (KITTI)")
    ev.set_defaults(func=cmd_eval)

    from .training.cli import add_parser

    add_parser(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.threads:
        import mipnet

        mipnet.set_num_threads(args.threads)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
