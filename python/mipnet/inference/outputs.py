"""The outputs of one pair under ``OUT/NAME``, and the whole per-pair path: read, run the network, write.

``NAME_disp.npy`` / ``.pfm`` / ``.png`` always; ``NAME_conf.npy`` / ``.png`` with the match confidence;
``NAME_depth.npy`` and ``NAME_points.ply`` with a calibration. Every file is written atomically
(:func:`mipnet.utils.files.atomic_write`), so a file that exists is whole, and a pair whose expected files all
exist is done (:meth:`OutputWriter.complete`): what a resumed Ray run skips (:mod:`mipnet.distributed.infer`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..stereo.rectify import Rectifier
from .pairs import read_pair


@dataclasses.dataclass(frozen=True)
class OutputOptions:
    """What is written for a pair besides its disparity, and how it is shown (``mipnet infer``'s flags).

    Attributes
    ----------
    confidence : bool
        Also write the match confidence (``NAME_conf.npy`` / ``.png``).
    min_confidence : float or None
        Mark pixels whose confidence is below it invalid (inf in .npy/.pfm); implies ``confidence``.
    vmin, vmax : float or None
        Disparities shown darkest and brightest in ``NAME_disp.png`` (default: the 1st and 99th percentile).
    z_far : float or None
        With a calibration: leave points farther than this (metres) out of the point cloud.
    """

    confidence: bool = False
    min_confidence: float | None = None
    vmin: float | None = None
    vmax: float | None = None
    z_far: float | None = None


def _write_npy(path: str, array: np.ndarray) -> None:
    from ..utils.files import atomic_write

    with atomic_write(path) as f:
        np.save(f, array)


class OutputWriter:
    """Writes the outputs of one pair under ``out/NAME``: disparity, and confidence, depth, points as asked.

    ``options`` is an :class:`OutputOptions`, or anything with its attributes (the ``argparse`` namespace of
    ``mipnet infer``); ``calib`` a calibration of :func:`mipnet.stereo.io.read_calib`, a
    :class:`mipnet.stereo.rectify.Rectifier` (pairs rectified when read: also ``NAME_rectified.png``), or None."""

    def __init__(self, options, out: Path, calib):
        self.args, self.out, self.calib = options, Path(out), calib

    def _with_confidence(self) -> bool:
        return bool(self.args.confidence or self.args.min_confidence is not None)

    def outputs(self, name: str) -> list[Path]:
        """Every file :meth:`__call__` writes for the pair ``name``, in the order it writes them."""
        suffixes = (["_conf.npy", "_conf.png"] if self._with_confidence() else []) + ["_disp.npy", "_disp.pfm", "_disp.png"]
        suffixes += ["_depth.npy", "_points.ply"] if self.calib is not None else []
        suffixes += ["_rectified.png"] if isinstance(self.calib, Rectifier) else []
        return [self.out / f"{name}{suffix}" for suffix in suffixes]

    def complete(self, name: str) -> bool:
        """Whether every output of the pair ``name`` exists (each was written atomically, so each is whole)."""
        return all(path.is_file() for path in self.outputs(name))

    def __call__(self, name: str, left: np.ndarray, right: np.ndarray, disp: np.ndarray) -> None:
        from ..stereo import geometry, io, viz
        from ..stereo.confidence import match_confidence

        args, stem = self.args, self.out / name
        if self._with_confidence():
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
            # a rig calibration (Rectifier): the pair was rectified when read; depth from the rectified camera
            calib = self.calib.calibration(left.shape[:2]) if isinstance(self.calib, Rectifier) else self.calib
            depth = geometry.disparity_to_depth(disp, calib)
            _write_npy(f"{stem}_depth.npy", depth)
            points, colors = geometry.depth_to_points(depth, calib, image=left, z_far=args.z_far)
            io.write_ply(f"{stem}_points.ply", points, colors)
            if isinstance(self.calib, Rectifier):
                io.write_image(f"{stem}_rectified.png", left)


def infer_pair(model, left_path: str, right_path: str, name: str, write: OutputWriter, iters: Sequence[int],
               seed: int, scale: float, read: Callable = read_pair) -> None:
    """One pair alone, start to end: read it (``read``, by default :func:`read_pair`), run
    ``model(left, right, ...)`` on it and write its outputs, as ``mipnet infer --batch-size 1`` does each pair;
    what every Ray actor does (:mod:`mipnet.distributed.infer`)."""
    left, right = read(left_path, right_path)
    write(name, left, right, model(left, right, iters=tuple(iters), seed=seed, scale=scale))
