"""``mipnet infer``: disparity (and depth, a point cloud, the match confidence) for stereo pairs.

    mipnet infer                                              # the bundled example pair -> mipnet_out/
    mipnet infer -l 'left/*.png' -r 'right/*.png' -o out      # pairs by sorted name: out/NAME_disp.*
    mipnet infer -l 'mb/*/im0.png' -r 'mb/*/im1.png' -o out   # one folder per scene: out/SCENE_disp.*
    mipnet infer -l 'mb/*' -o out                             # the same: folders holding im0.png/im1.png
    mipnet infer --video left.mp4 right.mp4 -o out            # a stereo video, warm start (mipnet.cli.stream)

Outputs are named after the left image's file name (``NAME_disp.npy``, ``.pfm``, ``.png``), or, when
file names repeat within the run (Middlebury, ETH3D: one folder per scene, the same names in each) or
``-l`` names folders, after the folder of the pair, as RAFT-Stereo's demo does. No output of a run is
written twice: two inputs that would still share a name stop the run before any work.

Consecutive pairs of one size go through the network together, ``--batch-size`` at a time; each
pair's initial disparities are drawn as a run of that pair alone draws them, so a batch gives the
disparities of one-pair runs to float rounding (within 1e-4 px); a single pair runs exactly as the
Python API's ``model(left, right)``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Iterator

import numpy as np

from ..amp import autocast
from ..errors import ArgumentError
from ..inference.outputs import OutputWriter
from ..inference.pairs import pair_reader, read_pair, resolve_pairs
from ..stereo.rectify import open_calibration
from .common import (USER_ERRORS, Failures, PairError, add_iters, add_precision, load_model, naming, positive_float,
                     positive_int, progress_bar, unit_fraction)
from .distributed import add_ray_arguments, infer_on_ray
from .stream import add_stream_arguments, run_stream, wants_stream


DEFAULT_BATCH_SIZE = 2


def add_parser(sub) -> argparse.ArgumentParser:
    """Registers ``infer`` on the ``mipnet`` sub-command parsers."""
    p = sub.add_parser("infer", help="disparity (and depth, point cloud) for stereo pairs",
                       description="Disparity maps (.npy, .pfm, colour .png) for stereo pairs; with --calib also "
                                   "depth and a point cloud. Outputs are named after the left image, or after its "
                                   "folder when file names repeat (one folder per scene).")
    p.add_argument("-l", "--left", metavar="PATH",
                   help="left image, glob (quote it), or folder(s) holding a pair: im0.png/im1.png or "
                        "left.*/right.* (then -r may be left out) (default: the bundled example pair)")
    p.add_argument("-r", "--right", metavar="PATH", help="right image or glob, in the same sorted order as --left")
    p.add_argument("-o", "--output-directory", dest="output_directory", metavar="DIR", default="mipnet_out",
                   help="folder for the outputs, created if needed (default mipnet_out): NAME_disp.npy/.pfm/.png, "
                        "and NAME_conf.*, NAME_depth.npy, NAME_points.ply as asked")
    p.add_argument("--weights", metavar="FILE", help="weights file (.safetensors written by MIPNet.save; "
                                                     "default: the shipped weights)")
    add_iters(p)
    p.add_argument("--batch-size", type=positive_int, default=None, metavar="N",
                   help=f"run up to N consecutive pairs of one size through the network together (default "
                        f"{DEFAULT_BATCH_SIZE}; faster per pair, N times the memory; 1: one pair at a time)")
    p.add_argument("--calib", metavar="FILE",
                   help="calib.txt (Middlebury/ETH3D) or K.txt: also write depth (NAME_depth.npy) and a point cloud "
                        "(NAME_points.ply); an OpenCV stereo rig calibration (.yml/.yaml/.xml/.json: K1 D1 K2 D2 R "
                        "T) rectifies raw pairs first and writes depth in the units of T, the disparity in the "
                        "rectified frame and the rectified left image (NAME_rectified.png) (docs/calibration.md)")
    p.add_argument("--rectify-alpha", dest="rectify_alpha", type=float, default=None, metavar="A",
                   help="with a rig --calib: stereoRectify's free scaling, 0 (default) only pixels both raw images "
                        "see, 1 every raw pixel (black borders)")
    p.add_argument("--z-far", type=positive_float, default=None, metavar="Z",
                   help="with --calib: leave points farther than Z metres out of the point cloud")
    p.add_argument("--vmin", type=float, default=None,
                   help="disparity shown darkest in NAME_disp.png (default: the 1st percentile)")
    p.add_argument("--vmax", type=float, default=None,
                   help="disparity shown brightest in NAME_disp.png (default: the 99th percentile)")
    p.add_argument("--seed", type=int, default=20, help="seed of the gamma initialisation (default 20)")
    p.add_argument("--scale", type=positive_float, default=1.0,
                   help="resize the pair by this factor before the network, the disparity back (default 1; "
                        "e.g. 0.5 for photographs whose disparities exceed ~160 px)")
    p.add_argument("--confidence", action="store_true",
                   help="also write the match confidence (NAME_conf.npy / .png): near 1 where both views show the "
                        "same texture at the disparity, near 0 where the disparity is a guess (open water, sky, "
                        "occlusions)")
    p.add_argument("--min-confidence", type=unit_fraction, default=None, metavar="C",
                   help="mark pixels whose match confidence is below C invalid (inf in .npy/.pfm, black in .png, "
                        "no depth or point); 0.5 keeps ~97%% of the pixels in air and drops open water under a "
                        "veil (docs/training.md); implies --confidence")
    add_precision(p)
    add_stream_arguments(p)
    add_ray_arguments(p, "with --ray: Ray actors, each holding one model and running on its node's "
                         "cores / actors there (default: one per node)")
    p.set_defaults(func=run)
    return p


# ---- running the network -----------------------------------------------------------------------------


def predict(model, images: list[tuple[np.ndarray, np.ndarray]], iters, seed: int, scale: float) -> list[np.ndarray]:
    """The disparity of each pair (all of one size), in one pass of the network. One pair runs as
    ``model(left, right, ...)``; in a batch each pair starts from the seed's draw of its own run, so batching
    changes only float rounding."""
    if len(images) == 1:
        left, right = images[0]
        return [model(left, right, iters=iters, seed=seed, scale=scale)]
    lefts = np.stack([left.transpose(2, 0, 1) for left, _ in images]).astype(np.float32)
    rights = np.stack([right.transpose(2, 0, 1) for _, right in images]).astype(np.float32)
    return list(model(lefts, rights, iters=iters, seed=seed, scale=scale))


def _batches(pairs: list[tuple[str, str, str]], size: int, failures: Failures, progress,
             read=read_pair) -> Iterator[list[tuple]]:
    """Lists of at most ``size`` consecutive readable pairs of one image size: (left, right, name, images);
    a pair that ``read`` cannot read is recorded in ``failures``, counted on ``progress`` and left out."""
    batch: list[tuple] = []
    for lp, rp, name in pairs:
        images = failures.attempt((lp, rp), read, lp, rp)
        if images is None:
            progress.update(1)
            continue
        if batch and (len(batch) == size or batch[0][3][0].shape != images[0].shape):
            yield batch
            batch = []
        batch.append((lp, rp, name, images))
    if batch:
        yield batch


def run(args: argparse.Namespace) -> int:
    with autocast(enabled=args.precision == "bf16"):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    if wants_stream(args):  # a stereo video: mipnet.cli.stream
        return run_stream(args)
    if args.vmin is not None and args.vmax is not None and not args.vmin < args.vmax:
        raise ArgumentError(f"--vmin {args.vmin} must be below --vmax {args.vmax}")
    if args.z_far is not None and not args.calib:
        raise ArgumentError("--z-far needs --calib (the point cloud is written only with a calibration)")
    if args.rectify_alpha is not None and not args.calib:
        raise ArgumentError("--rectify-alpha needs --calib with a stereo rig calibration (docs/calibration.md)")
    pairs = resolve_pairs(args.left, args.right)
    # calib.txt / K.txt: a dict for rectified pairs; an OpenCV rig calibration: a Rectifier for raw pairs
    calib = open_calibration(args.calib, args.rectify_alpha) if args.calib else None
    read = pair_reader(calib)  # rectified first with a rig calibration
    ray_status = infer_on_ray(args, calib, read)  # --ray: mipnet.cli.distributed
    if ray_status is not None:
        return ray_status
    # a single pair is checked before the model loads, so that its error is the only line printed
    first = read(*pairs[0][:2]) if len(pairs) == 1 else None
    model = load_model(args.weights)
    out = Path(args.output_directory)
    out.mkdir(parents=True, exist_ok=True)
    write = OutputWriter(args, out, calib)
    iters = tuple(args.iters)

    if first is not None:  # a single pair: its error is the command's error (status 2)
        lp, rp, name = pairs[0]
        try:
            write(name, *first, predict(model, [first], iters, args.seed, args.scale)[0])
        except USER_ERRORS as error:
            raise PairError(naming((lp, rp), error)) from error
        print(f"wrote 1 disparity map to {out}/")
        return 0
    failures = Failures("mipnet infer", args.debug)

    def finish(name: str, images: tuple[np.ndarray, np.ndarray], disp: np.ndarray | None) -> bool:
        if disp is None:
            disp = predict(model, [images], iters, args.seed, args.scale)[0]
        write(name, *images, disp)
        return True

    written = 0
    with progress_bar(len(pairs), "infer") as progress:
        for batch in _batches(pairs, args.batch_size or DEFAULT_BATCH_SIZE, failures, progress, read):
            disparities: list = [None] * len(batch)
            if len(batch) > 1:
                try:
                    disparities = predict(model, [item[3] for item in batch], iters, args.seed, args.scale)
                except USER_ERRORS:
                    pass  # too large together (memory), or one pair's own error: each pair alone says which
            for (lp, rp, name, images), disp in zip(batch, disparities):
                written += bool(failures.attempt((lp, rp), finish, name, images, disp))
                progress.set_postfix_str(Path(lp).name, refresh=False)
                progress.update(1)
    print(f"wrote {written} disparity map(s) to {out}/")
    return failures.report(len(pairs))
