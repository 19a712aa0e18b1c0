"""Which stereo pairs a path or glob names, the names of their outputs, and reading one pair.

Outputs are named after the left image's file name (``NAME_disp.npy``, ``.pfm``, ``.png``), or, when file names
repeat within the run (Middlebury, ETH3D: one folder per scene, the same names in each) or ``-l`` names folders,
after the folder of the pair, as RAFT-Stereo's demo does. Two inputs that would still share a name are an error
before any work, so no output of a run is written twice.
"""

from __future__ import annotations

import errno
import glob
import os
from pathlib import Path

import numpy as np

from ..data.example import EXAMPLE_LEFT, EXAMPLE_RIGHT
from ..errors import ArgumentError, ShapeError
from ..stereo.rectify import Rectifier

#: what a folder given as ``-l`` holds, tried in order: Middlebury / ETH3D names, then left.* / right.*
FOLDER_LAYOUTS = (("im0.png", "im1.png"), ("left.*", "right.*"))
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".pnm", ".bmp", ".tif", ".tiff", ".webp"}


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


class RectifiedReader:
    """Reads a raw pair (:func:`read_pair`) and rectifies it with a rig calibration: ``reader(left_path, right_path)
    -> (left, right)``, as ``mipnet infer --calib rig.yml`` reads its pairs (picklable, for Ray's actors)."""

    def __init__(self, rectifier: Rectifier):
        self.rectifier = rectifier

    def __call__(self, left_path: str, right_path: str) -> tuple[np.ndarray, np.ndarray]:
        left, right = self.rectifier.rectify(*read_pair(left_path, right_path))[:2]
        return left, right


def pair_reader(calib):
    """How the pairs of a run with the calibration ``calib`` are read: rectified for a rig calibration
    (:class:`mipnet.stereo.rectify.Rectifier`), as they are otherwise (:func:`read_pair`)."""
    return RectifiedReader(calib) if isinstance(calib, Rectifier) else read_pair
