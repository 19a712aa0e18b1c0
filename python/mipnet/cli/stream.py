"""``mipnet infer --video / --sbs / --sequence``: disparity for the frames of a stereo video, warm-started frame to
frame (:class:`mipnet.Stream`), and an mp4 of it in one colour range (docs/video.md).

    mipnet infer --video left.mp4 right.mp4 -o out      # one video per camera
    mipnet infer --sbs rov.mp4 -o out                   # side by side: left half | right half
    mipnet infer --sequence -l 'L/*.png' -r 'R/*.png'   # sorted image sequences, one per camera

Each frame gets ``NAME_disp.npy``, ``.pfm`` and ``.png`` as ``mipnet infer`` writes them for a pair (NAME: the video's
name and the frame number, or the left image's name), and the sequence ``STEM_disp.mp4`` (H.264) with
``STEM_disp_range.json``. The PNGs and the video share one colour range: ``--vmin`` / ``--vmax`` if given, else the
1st and 99th percentile of every disparity of the sequence, pooled, from a second pass over the saved ``.npy`` files
(:func:`mipnet.stereo.video.pooled_percentiles`). The first frame, and any frame after a reset, runs cold with
``--iters``; the others warm with ``--warm-iters``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..errors import ArgumentError, FormatError
from ..model.stream import DEFAULT_ITERS, DEFAULT_RESET, Stream
from ..stereo import io
from ..stereo.video import DEFAULT_FPS, DisparityVideo, ImagePairs, SideBySide, VideoPair, pooled_percentiles
from ..stereo.viz import colorize
from ..utils.files import atomic_write
from .common import Iters, load_model, positive_float, progress_bar, require_module

#: the warm iterations of ``--warm-iters``: the stream's (docs/video.md: what the measurements picked)
DEFAULT_WARM_ITERS = DEFAULT_ITERS
#: options of ``mipnet infer`` for pairs that a video run does not take
_PAIR_ONLY = (("calib", "--calib"), ("rectify_alpha", "--rectify-alpha"), ("confidence", "--confidence"),
              ("min_confidence", "--min-confidence"), ("z_far", "--z-far"), ("ray", "--ray"))


def add_warm_arguments(parser: argparse.ArgumentParser, context: str) -> None:
    """``--warm-iters`` and ``--reset``, the settings of a :class:`mipnet.Stream` (``context``: when they apply)."""
    parser.add_argument("--warm-iters", dest="warm_iters", type=int, nargs=2, default=DEFAULT_WARM_ITERS,
                        metavar=("N16", "N4"), action=Iters,
                        help=f"{context}: iterations of the warm-started frames (default {DEFAULT_WARM_ITERS[0]} "
                             f"{DEFAULT_WARM_ITERS[1]}); --iters is the cold frames' (the first, and after a reset)")
    parser.add_argument("--reset", type=positive_float, default=DEFAULT_RESET, metavar="R",
                        help=f"{context}: restart cold when the previous disparity's photometric error on the new "
                             f"frame is above R times its error on its own frame (default {DEFAULT_RESET})")


def add_stream_arguments(parser: argparse.ArgumentParser) -> None:
    """``--video``, ``--sbs``, ``--sequence`` (one of them), ``--warm-iters``, ``--reset`` and ``--fps`` on
    ``mipnet infer``'s parser."""
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--video", nargs=2, metavar=("LEFT.mp4", "RIGHT.mp4"),
                        help="a stereo video as two files, one per camera: every frame pair, warm-started from the "
                             "previous frame (mipnet.Stream), and NAME_disp.mp4 in one colour range (docs/video.md)")
    source.add_argument("--sbs", metavar="VIDEO",
                        help="a side-by-side stereo video (left view in the left half of each frame), as --video")
    source.add_argument("--sequence", action="store_true",
                        help="-l / -r name sorted image sequences (globs), one per camera: run them as a video")
    add_warm_arguments(parser, "with --video / --sbs / --sequence")
    parser.add_argument("--fps", type=positive_float, default=None,
                        help=f"frame rate of the disparity video of --sequence (default {DEFAULT_FPS:g}); a video's "
                             "own rate otherwise")


def wants_stream(args: argparse.Namespace) -> bool:
    """Whether the command line asks for a video run."""
    return bool(args.video or args.sbs or args.sequence)


def _source(args: argparse.Namespace):
    """The frame pairs the command line names: VideoPair, SideBySide or ImagePairs."""
    from ..inference.pairs import resolve_pairs

    if args.sequence:
        if not (args.left and args.right):
            raise ArgumentError("--sequence needs -l 'LEFT_GLOB' and -r 'RIGHT_GLOB' (sorted image sequences)")
        return ImagePairs(resolve_pairs(args.left, args.right), fps=args.fps or DEFAULT_FPS)
    if args.left or args.right:
        raise ArgumentError("--video and --sbs name the input themselves: leave out -l / -r")
    if args.fps is not None:
        raise ArgumentError("--fps is for --sequence (a video keeps its own frame rate)")
    return VideoPair(*args.video) if args.video else SideBySide(args.sbs)


def _check_options(args: argparse.Namespace) -> None:
    given = [flag for name, flag in _PAIR_ONLY if getattr(args, name, None) not in (None, False)]
    if given:
        raise ArgumentError(f"{', '.join(given)}: for pairs of images; a --video / --sbs / --sequence run writes the "
                            "disparity frames and their video only")
    if args.vmin is not None and args.vmax is not None and not args.vmin < args.vmax:
        raise ArgumentError(f"--vmin {args.vmin} must be below --vmax {args.vmax}")


def _save_npy(path: Path, array: np.ndarray) -> None:
    with atomic_write(path) as f:
        np.save(f, array)


def _colour_range(args: argparse.Namespace, saved) -> tuple[float, float, str]:
    """(vmin, vmax, how it was chosen) of the whole sequence: ``--vmin`` / ``--vmax`` where given, else the pooled
    1st / 99th percentile of the saved disparities (``saved()`` yields them)."""
    if args.vmin is not None and args.vmax is not None:
        return args.vmin, args.vmax, "fixed by --vmin / --vmax"
    low, high = pooled_percentiles(saved)
    if low == high and args.vmin is None and args.vmax is None:  # one disparity everywhere: a range around it
        low, high = low - 0.5, high + 0.5
    vmin = args.vmin if args.vmin is not None else low
    vmax = args.vmax if args.vmax is not None else high
    if not vmin < vmax:
        raise ArgumentError(f"the colour range {vmin:g}..{vmax:g} px is empty: --vmin must lie below the sequence's "
                            f"99th percentile ({high:g} px) and --vmax above its 1st ({low:g} px)")
    return vmin, vmax, "1st and 99th percentile of every frame's disparity, pooled, where not given"


def run_stream(args: argparse.Namespace) -> int:
    """Runs the frames through a :class:`mipnet.Stream`, writes each frame's disparity, then the PNGs and the video
    in one colour range. Any error stops the run (a video is one sequence), naming the file."""
    _check_options(args)
    require_module("av", "av", "--video / --sbs / --sequence (video input and the disparity video)")
    source = _source(args)
    model = load_model(args.weights)
    out = Path(args.output_directory)
    out.mkdir(parents=True, exist_ok=True)
    stream = Stream(model, tuple(args.warm_iters), cold_iters=tuple(args.iters), reset=args.reset, seed=args.seed,
                    scale=args.scale)
    names: list[str] = []
    with progress_bar(source.count, "infer", unit="frame") as progress:
        for name, left, right in source:
            disp = stream(left, right)
            _save_npy(out / f"{name}_disp.npy", disp)
            io.write_pfm(out / f"{name}_disp.pfm", disp)
            names.append(name)
            progress.update(1)
    if not names:
        raise FormatError(f"{source.stem}: the input holds no frame")

    def saved():
        return (np.load(out / f"{name}_disp.npy") for name in names)

    vmin, vmax, how = _colour_range(args, saved)
    video_path = out / f"{source.stem}_disp.mp4"
    size = np.load(out / f"{names[0]}_disp.npy", mmap_mode="r").shape
    with DisparityVideo(video_path, source.fps, size, vmin, vmax) as video:
        for name, disp in zip(names, saved()):
            io.write_image(out / f"{name}_disp.png", colorize(disp, vmin=vmin, vmax=vmax))
            video.write(disp)
    with atomic_write(out / f"{source.stem}_disp_range.json", "w") as f:
        json.dump({"vmin": vmin, "vmax": vmax, "range": how, "colormap": "turbo", "frames": len(names),
                   "fps": source.fps, "warm_iters": list(args.warm_iters), "cold_iters": list(args.iters),
                   "resets": stream.resets}, f, indent=1)
    print(f"wrote {len(names)} disparity frames and {video_path.name} (colour range {vmin:.2f}..{vmax:.2f} px; "
          f"{len(stream.resets)} reset(s)) to {out}/")
    return 0
