"""``mipnet infer``: disparity (and depth, a point cloud, the match confidence) for stereo pairs.

    mipnet infer                                              # the bundled example pair -> mipnet_out/
    mipnet infer -l 'left/*.png' -r 'right/*.png' -o out      # pairs by sorted name: out/NAME_disp.*
    mipnet infer -l 'mb/*/im0.png' -r 'mb/*/im1.png' -o out   # one folder per scene: out/SCENE_disp.*
    mipnet infer -l 'mb/*' -o out                             # the same: folders holding im0.png/im1.png

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
import errno
import glob
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from ..data.example import EXAMPLE_LEFT, EXAMPLE_RIGHT
from ..errors import ArgumentError, ShapeError
from .common import (USER_ERRORS, Failures, PairError, add_iters, load_model, naming, positive_float, positive_int,
                     progress_bar, unit_fraction)


#: what a folder given as ``-l`` holds, tried in order: Middlebury / ETH3D names, then left.* / right.*
FOLDER_LAYOUTS = (("im0.png", "im1.png"), ("left.*", "right.*"))
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm", ".bmp", ".tif", ".tiff", ".webp"}
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
    p.add_argument("--batch-size", type=positive_int, default=DEFAULT_BATCH_SIZE, metavar="N",
                   help=f"run up to N consecutive pairs of one size through the network together (default "
                        f"{DEFAULT_BATCH_SIZE}; faster per pair, N times the memory; 1: one pair at a time)")
    p.add_argument("--calib", metavar="FILE",
                   help="calib.txt (Middlebury/ETH3D) or K.txt: also write depth (NAME_depth.npy) and a point cloud "
                        "(NAME_points.ply)")
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
    p.set_defaults(func=run)
    return p


# ---- which pairs, and the names of their outputs --------------------------------------------------


def _expand(pattern: str) -> list[str]:
    """The files a path or glob names, sorted; FileNotFoundError if there are none."""
    if any(c in pattern for c in "*?["):
        paths = sorted(p for p in glob.glob(pattern) if os.path.isfile(p))
        if not paths:
            raise FileNotFoundError(errno.ENOENT, "no file matches this pattern", pattern)
        return paths
    if not os.path.exists(pattern):
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), pattern)
    if not os.path.isfile(pattern):
        raise IsADirectoryError(errno.EISDIR, "not a file", pattern)
    return [pattern]


def _folders(pattern: str) -> list[str]:
    """The folders a path or glob names, sorted (none for a file, or a glob that matches only files)."""
    if any(c in pattern for c in "*?["):
        return sorted(p for p in glob.glob(pattern) if os.path.isdir(p))
    return [pattern] if os.path.isdir(pattern) else []


def _folder_name(path: str) -> str:
    return os.path.basename(os.path.normpath(os.path.abspath(path)))


def folder_pair(folder: str) -> tuple[str, str]:
    """The left and right images in ``folder`` (:data:`FOLDER_LAYOUTS`); ArgumentError naming it if none."""
    for left, right in FOLDER_LAYOUTS:
        found = []
        for name in (left, right):
            paths = [p for p in glob.glob(os.path.join(glob.escape(folder), name))
                     if os.path.isfile(p) and Path(p).suffix.lower() in IMAGE_SUFFIXES]
            found.append(paths)
        if all(len(paths) == 1 for paths in found):
            return found[0][0], found[1][0]
    raise ArgumentError(f"{folder}: no stereo pair in this folder (expected im0.png and im1.png, or one left.* "
                        "and one right.* image)")


def output_names(lefts: list[str]) -> list[str]:
    """The name each pair's outputs get: the left file's name without its suffix, or, when those repeat
    in the run, the name of the left file's folder (the scene)."""
    stems = [Path(path).stem for path in lefts]
    return stems if len(set(stems)) == len(stems) else [_folder_name(os.path.dirname(path) or ".") for path in lefts]


def resolve_pairs(left: str | None, right: str | None) -> list[tuple[str, str, str]]:
    """(left image, right image, output name) of every pair the command line names, in order; an error
    before any work if they cannot be paired or two pairs would write the same outputs."""
    if left is None and right is None:
        return [(str(EXAMPLE_LEFT), str(EXAMPLE_RIGHT), EXAMPLE_LEFT.stem)]
    if left is None:
        raise ArgumentError("give both -l/--left and -r/--right, or neither (bundled example pair)")
    folders = _folders(left) if right is None or right == left else []
    if folders:
        pairs = [(*folder_pair(folder), _folder_name(folder)) for folder in folders]
    elif right is None:
        raise ArgumentError("give both -l/--left and -r/--right, or neither (bundled example pair), or as -l a "
                            "folder holding im0.png/im1.png or left.*/right.*")
    else:
        lefts, rights = _expand(left), _expand(right)
        if len(lefts) != len(rights):
            raise ArgumentError(f"{len(lefts)} left images ({left}) but {len(rights)} right images ({right})")
        pairs = list(zip(lefts, rights, output_names(lefts)))
    first: dict[str, str] = {}
    for lp, _, name in pairs:
        if name in first:
            raise ArgumentError(f"{first[name]} and {lp} would both write the outputs {name}_disp.*: give them "
                                "distinct file or folder names, or run them into different --output-directory "
                                "folders")
        first[name] = lp
    return pairs


def read_pair(left_path: str, right_path: str) -> tuple[np.ndarray, np.ndarray]:
    """The two images of a stereo pair as RGB uint8; ShapeError naming both files if their sizes differ
    or are below the model's minimum."""
    from ..stereo import io
    from ..model.network import MIN_SIZE

    left, right = io.read_image(left_path), io.read_image(right_path)
    (lh, lw), (rh, rw) = left.shape[:2], right.shape[:2]
    if (lh, lw) != (rh, rw):
        raise ShapeError(f"{left_path} is {lh}x{lw} (HxW) but {right_path} is {rh}x{rw}: "
                         "the two images of a pair must have one size")
    if min(lh, lw) < MIN_SIZE:
        raise ShapeError(f"{left_path} is {lh}x{lw} (HxW): MIPNet needs images of at least {MIN_SIZE}x{MIN_SIZE}")
    return left, right


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


def _write_npy(path: str, array: np.ndarray) -> None:
    from ..utils.files import atomic_write

    with atomic_write(path) as f:
        np.save(f, array)


class Writer:
    """Writes the outputs of one pair under ``out/NAME``: disparity, and confidence, depth, points as asked."""

    def __init__(self, args: argparse.Namespace, out: Path, calib):
        self.args, self.out, self.calib = args, out, calib

    def __call__(self, name: str, left: np.ndarray, right: np.ndarray, disp: np.ndarray) -> None:
        from ..stereo import geometry, io, viz
        from ..stereo.confidence import match_confidence

        args, stem = self.args, self.out / name
        if args.confidence or args.min_confidence is not None:
            confidence = match_confidence(left, right, disp)
            _write_npy(f"{stem}_conf.npy", confidence)
            io.write_image(f"{stem}_conf.png", viz.colorize(confidence, vmin=0.0, vmax=1.0, cmap="gray"))
            if args.min_confidence is not None:
                # pixels the images do not back are invalid (inf, the Middlebury convention)
                disp = np.where(confidence >= args.min_confidence, disp, np.float32(np.inf))
        _write_npy(f"{stem}_disp.npy", disp)
        io.write_pfm(f"{stem}_disp.pfm", disp)
        io.write_image(f"{stem}_disp.png", viz.colorize(disp, vmin=args.vmin, vmax=args.vmax))
        if self.calib is not None:
            depth = geometry.disparity_to_depth(disp, self.calib)
            _write_npy(f"{stem}_depth.npy", depth)
            points, colors = geometry.depth_to_points(depth, self.calib, image=left, z_far=args.z_far)
            io.write_ply(f"{stem}_points.ply", points, colors)


def _batches(pairs: list[tuple[str, str, str]], size: int, failures: Failures, progress) -> Iterator[list[tuple]]:
    """Lists of at most ``size`` consecutive readable pairs of one image size: (left, right, name, images);
    a pair that cannot be read is recorded in ``failures``, counted on ``progress`` and left out."""
    batch: list[tuple] = []
    for lp, rp, name in pairs:
        images = failures.attempt((lp, rp), read_pair, lp, rp)
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
    from ..stereo import io

    if args.vmin is not None and args.vmax is not None and not args.vmin < args.vmax:
        raise ArgumentError(f"--vmin {args.vmin} must be below --vmax {args.vmax}")
    if args.z_far is not None and not args.calib:
        raise ArgumentError("--z-far needs --calib (the point cloud is written only with a calibration)")
    pairs = resolve_pairs(args.left, args.right)
    calib = io.read_calib(args.calib) if args.calib else None
    # a single pair is checked before the model loads, so that its error is the only line printed
    first = read_pair(*pairs[0][:2]) if len(pairs) == 1 else None
    model = load_model(args.weights)
    out = Path(args.output_directory)
    out.mkdir(parents=True, exist_ok=True)
    write = Writer(args, out, calib)
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
        for batch in _batches(pairs, args.batch_size, failures, progress):
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
