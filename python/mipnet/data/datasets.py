"""Map-style stereo datasets in their official folder layouts.

Every dataset's ``__getitem__`` returns a dict:

* ``left``, ``right``: (H, W, 3) uint8 RGB;
* ``disparity``: (H, W) float32 left-view disparity in px, 0 where invalid;
* ``valid``: (H, W) bool;
* ``meta``: dict with the file paths (``left``, ``right``, ``disparity``, ...), the dataset name
  and the index. Splits without ground truth return zeros / all-False and ``meta["has_gt"]``
  False.

Datasets concatenate with ``+`` and repeat with ``* k`` (RAFT-Stereo habit)::

    train = SceneFlow(root) + 10 * KITTI(kitti_root)
"""

from __future__ import annotations

import glob
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..stereo.io import read_crestereo_disparity, read_image, read_kitti_disparity, read_npy, read_pfm
from ..utils.data.dataset import ConcatDataset, Dataset, RepeatDataset

__all__ = [
    "Dataset",
    "ConcatDataset",
    "RepeatDataset",
    "StereoDataset",
    "SceneFlow",
    "Middlebury2014",
    "MiddEval3",
    "ETH3D",
    "KITTI",
    "CREStereo",
    "FolderPairs",
]

SCENEFLOW_MAX_DISPARITY = 512.0


# ------------------------------------------------------------------------- file-based sets


@dataclass(frozen=True)
class _Sample:
    left: str
    right: str
    disparity: str | None = None
    mask: str | None = None
    calib: str | None = None


def _pfm_disparity(path: str) -> np.ndarray:
    disparity = read_pfm(path)
    # Three-channel PFMs carry the disparity in the first channel.
    return disparity[:, :, 0] if disparity.ndim == 3 else disparity


def _read_finite_pfm(sample: _Sample) -> tuple[np.ndarray, np.ndarray]:
    """Middlebury / ETH3D: inf marks pixels without ground truth."""
    disparity = _pfm_disparity(sample.disparity)
    return disparity, np.isfinite(disparity) & (disparity > 0)


def _read_sceneflow_pfm(sample: _Sample) -> tuple[np.ndarray, np.ndarray]:
    disparity = np.abs(_pfm_disparity(sample.disparity))
    return disparity, np.isfinite(disparity) & (disparity < SCENEFLOW_MAX_DISPARITY)


def _read_kitti(sample: _Sample) -> tuple[np.ndarray, np.ndarray]:
    return read_kitti_disparity(sample.disparity)


def _read_crestereo(sample: _Sample) -> tuple[np.ndarray, np.ndarray]:
    return read_crestereo_disparity(sample.disparity)


def _read_npy(sample: _Sample) -> tuple[np.ndarray, np.ndarray]:
    disparity = read_npy(sample.disparity).astype(np.float32)
    return disparity, np.isfinite(disparity) & (disparity > 0)


class StereoDataset(Dataset):
    """A list of image-pair file samples plus the reader of their disparity files.

    Subclasses fill ``samples`` in ``__init__``; ``mask0nocc.png`` files (255 = non-occluded)
    restrict ``valid`` when ``occ`` is False.

    Parameters
    ----------
    samples : list of _Sample
        File paths of each pair.
    read_disparity : callable or None
        ``sample -> (disparity float32 (H, W), valid bool (H, W))``; None when no sample has
        ground truth.
    occ : bool
        True: evaluate all pixels with ground truth; False: only non-occluded ones (mask == 255).
    """

    name = "stereo"

    def __init__(self, samples: list[_Sample], read_disparity: Callable | None, occ: bool = True):
        self.samples = samples
        self._read_disparity = read_disparity
        self.occ = occ

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, index: int) -> dict:
        index = self._check_index(index)
        sample = self.samples[index]
        left = read_image(sample.left)
        right = read_image(sample.right)
        has_gt = sample.disparity is not None
        if has_gt:
            disparity, valid = self._read_disparity(sample)
            if not self.occ and sample.mask is not None:
                valid &= _nocc_mask(sample.mask)
            disparity = np.where(valid, disparity, 0).astype(np.float32)
        else:
            disparity = np.zeros(left.shape[:2], dtype=np.float32)
            valid = np.zeros(left.shape[:2], dtype=bool)
        meta = {"dataset": self.name, "index": index, "has_gt": has_gt, "left": sample.left,
                "right": sample.right, "disparity": sample.disparity, "mask": sample.mask, "calib": sample.calib}
        return {"left": left, "right": right, "disparity": disparity, "valid": valid, "meta": meta}


def _nocc_mask(path: str) -> np.ndarray:
    return read_image(path)[:, :, 0] == 255


def _require_masks(samples: list[_Sample]) -> None:
    """Non-occluded evaluation needs a mask0nocc.png next to every ground-truth file."""
    for sample in samples:
        if sample.disparity is not None and sample.mask is None:
            raise FileNotFoundError(f"occ=False needs mask0nocc.png for {sample.disparity}")


def _require(samples: list, where: str) -> list:
    if not samples:
        raise FileNotFoundError(f"no stereo pairs found under {where}")
    return samples


def _existing(path: str) -> str | None:
    return path if os.path.exists(path) else None


def _sorted_glob(*parts: str) -> list[str]:
    return sorted(glob.glob(os.path.join(*parts)))


def _swap_dir(path: str, old: str, new: str) -> str:
    """Replace the last path component equal to ``old`` by ``new``."""
    parts = path.split(os.sep)
    index = len(parts) - 1 - parts[::-1].index(old)
    parts[index] = new
    return os.sep.join(parts)


class SceneFlow(StereoDataset):
    """FlyingThings3D, Monkaa and Driving (frames_{clean,final}pass PNG + disparity PFM).

    Layout (``root`` holds the three subset folders)::

        FlyingThings3D/<dstype>/{TRAIN,TEST}/{A,B,C}/NNNN/{left,right}/NNNN.png
        FlyingThings3D/disparity/{TRAIN,TEST}/{A,B,C}/NNNN/left/NNNN.pfm
        Monkaa/<dstype>/<scene>/{left,right}/*.png,  Monkaa/disparity/<scene>/left/*.pfm
        Driving/<dstype>/<focal>/<direction>/<speed>/{left,right}/*.png, Driving/disparity/...

    Monkaa and Driving have no TEST split and are only used with ``split="TRAIN"``.
    ``valid`` = ``|d| < 512`` (disparity taken as ``|d|``).
    """

    name = "sceneflow"

    def __init__(self, root, dstype: str = "frames_cleanpass", split: str = "TRAIN",
                 subsets: Sequence[str] = ("FlyingThings3D", "Monkaa", "Driving")):
        if split not in ("TRAIN", "TEST"):
            raise ValueError(f"SceneFlow: split must be 'TRAIN' or 'TEST', got {split!r}")
        root = os.fspath(root)
        patterns = {
            "FlyingThings3D": ("FlyingThings3D", dstype, split, "*", "*", "left", "*.png"),
            "Monkaa": ("Monkaa", dstype, "*", "left", "*.png"),
            "Driving": ("Driving", dstype, "*", "*", "*", "left", "*.png"),
        }
        unknown = set(subsets) - set(patterns)
        if unknown:
            raise ValueError(f"SceneFlow: unknown subsets {sorted(unknown)}; expected {list(patterns)}")
        lefts = []
        for subset in subsets:
            if subset == "FlyingThings3D" or split == "TRAIN":
                lefts += _sorted_glob(root, *patterns[subset])
        samples = [
            _Sample(
                left=left,
                right=_swap_dir(left, "left", "right"),
                disparity=os.path.splitext(_swap_dir(left, dstype, "disparity"))[0] + ".pfm",
            )
            for left in lefts
        ]
        super().__init__(_require(samples, os.path.join(root, f"{{{','.join(subsets)}}}/{dstype}")),
                         _read_sceneflow_pfm)


class Middlebury2014(StereoDataset):
    """Middlebury 2014 full-size scenes: ``root/<Scene>-{perfect,imperfect}/{im0,im1,disp0.pfm,calib.txt}``.

    ``right_image`` picks ``im1`` (default), ``im1E`` (different exposure) or ``im1L`` (different
    lighting). ``inf`` disparity -> invalid.
    """

    name = "middlebury2014"

    def __init__(self, root, right_image: str = "im1"):
        if right_image not in ("im1", "im1E", "im1L"):
            raise ValueError(f"Middlebury2014: right_image must be im1, im1E or im1L, got {right_image!r}")
        root = os.fspath(root)
        samples = [
            _Sample(
                left=os.path.join(scene, "im0.png"),
                right=os.path.join(scene, f"{right_image}.png"),
                disparity=_existing(os.path.join(scene, "disp0.pfm")),
                calib=_existing(os.path.join(scene, "calib.txt")),
            )
            for scene in _sorted_glob(root, "*", "")
            if os.path.exists(os.path.join(scene, "im0.png"))
        ]
        super().__init__(_require(samples, root), _read_finite_pfm)


class MiddEval3(StereoDataset):
    """Middlebury v3: ``root/{training,test}{F,H,Q}/<scene>/{im0,im1,disp0GT.pfm,mask0nocc.png,calib.txt}``.

    ``occ=False`` restricts ``valid`` to ``mask0nocc == 255`` (non-occluded).
    """

    name = "middeval3"

    def __init__(self, root, split: str = "training", resolution: str = "H", occ: bool = True):
        if split not in ("training", "test") or resolution not in ("F", "H", "Q"):
            raise ValueError(f"MiddEval3: split training|test and resolution F|H|Q, got {split!r}, {resolution!r}")
        folder = os.path.join(os.fspath(root), f"{split}{resolution}")
        samples = [
            _Sample(
                left=os.path.join(scene, "im0.png"),
                right=os.path.join(scene, "im1.png"),
                disparity=_existing(os.path.join(scene, "disp0GT.pfm")),
                mask=_existing(os.path.join(scene, "mask0nocc.png")),
                calib=_existing(os.path.join(scene, "calib.txt")),
            )
            for scene in _sorted_glob(folder, "*", "")
            if os.path.exists(os.path.join(scene, "im0.png"))
        ]
        if not occ:
            _require_masks(samples)
        super().__init__(_require(samples, folder), _read_finite_pfm, occ=occ)


class ETH3D(StereoDataset):
    """ETH3D low-res two-view: images in ``two_view_{training,test}/<scene>/``, ground truth in
    ``two_view_training_gt/<scene>/{disp0GT.pfm, mask0nocc.png}``. Gray images become RGB.

    ``occ=False`` restricts ``valid`` to ``mask0nocc == 255``.
    """

    name = "eth3d"

    def __init__(self, root, split: str = "training", occ: bool = True):
        if split not in ("training", "test"):
            raise ValueError(f"ETH3D: split must be 'training' or 'test', got {split!r}")
        root = os.fspath(root)
        folder = os.path.join(root, f"two_view_{split}")
        samples = []
        for scene in _sorted_glob(folder, "*", ""):
            if not os.path.exists(os.path.join(scene, "im0.png")):
                continue
            gt = os.path.join(root, "two_view_training_gt", os.path.basename(os.path.normpath(scene)))
            samples.append(_Sample(
                left=os.path.join(scene, "im0.png"),
                right=os.path.join(scene, "im1.png"),
                disparity=_existing(os.path.join(gt, "disp0GT.pfm")) if split == "training" else None,
                mask=_existing(os.path.join(gt, "mask0nocc.png")) if split == "training" else None,
                calib=_existing(os.path.join(scene, "calib.txt")),
            ))
        if not occ:
            _require_masks(samples)
        super().__init__(_require(samples, folder), _read_finite_pfm, occ=occ)


class KITTI(StereoDataset):
    """KITTI 2015 / 2012 stereo (frame ``_10``).

    2015: ``root/{training,testing}/image_2|image_3/NNNNNN_10.png``, ``disp_occ_0|disp_noc_0``.
    2012: ``root/{training,testing}/colored_0|colored_1/NNNNNN_10.png``, ``disp_occ|disp_noc``.
    ``occ=True`` reads the all-pixel ground truth, ``occ=False`` the non-occluded one. Value 0 ->
    invalid.
    """

    name = "kitti"
    _FOLDERS = {2015: ("image_2", "image_3", "disp_occ_0", "disp_noc_0"),
                2012: ("colored_0", "colored_1", "disp_occ", "disp_noc")}

    def __init__(self, root, year: int = 2015, split: str = "training", occ: bool = True):
        if year not in self._FOLDERS or split not in ("training", "testing"):
            raise ValueError(f"KITTI: year 2012|2015 and split training|testing, got {year!r}, {split!r}")
        left_dir, right_dir, occ_dir, noc_dir = self._FOLDERS[year]
        folder = os.path.join(os.fspath(root), split)
        disp_dir = occ_dir if occ else noc_dir
        samples = [
            _Sample(
                left=left,
                right=os.path.join(folder, right_dir, os.path.basename(left)),
                disparity=os.path.join(folder, disp_dir, os.path.basename(left)) if split == "training" else None,
            )
            for left in _sorted_glob(folder, left_dir, "*_10.png")
        ]
        super().__init__(_require(samples, os.path.join(folder, left_dir)), _read_kitti)


class CREStereo(StereoDataset):
    """CREStereo synthetic data: ``root/**/<prefix>_left.jpg``, ``_right.jpg``, ``_left.disp.png`` (uint16 / 32)."""

    name = "crestereo"

    def __init__(self, root):
        root = os.fspath(root)
        lefts = sorted(glob.glob(os.path.join(root, "**", "*_left.jpg"), recursive=True))
        samples = [
            _Sample(
                left=left,
                right=left[: -len("_left.jpg")] + "_right.jpg",
                disparity=left[: -len("_left.jpg")] + "_left.disp.png",
            )
            for left in lefts
        ]
        super().__init__(_require(samples, root), _read_crestereo)


_DISPARITY_READERS = {"pfm": _read_finite_pfm, "kitti": _read_kitti, "crestereo": _read_crestereo, "npy": _read_npy}


def _guess_disparity_format(path: str) -> str:
    lower = path.lower()
    if lower.endswith(".disp.png"):
        return "crestereo"
    if lower.endswith(".png"):
        return "kitti"
    if lower.endswith(".pfm"):
        return "pfm"
    if lower.endswith(".npy"):
        return "npy"
    raise ValueError(f"FolderPairs: cannot tell the disparity format of {path!r}; pass disp_format")


class FolderPairs(StereoDataset):
    """Pairs from globs (sorted and matched by position), e.g. ``"scenes/*/im0.png"``.

    Parameters
    ----------
    left_glob, right_glob : str
        Patterns of left and right images; they must match the same number of files.
    disp_glob : str, optional
        Pattern of left disparity files; without it samples have no ground truth.
    disp_format : str, optional
        ``"pfm"`` (inf invalid), ``"kitti"`` (uint16 / 256), ``"crestereo"`` (uint16 / 32) or
        ``"npy"`` (float; non-finite or <= 0 invalid). Default: from the extension
        (``.disp.png`` -> crestereo, other ``.png`` -> kitti).
    """

    name = "folder"

    def __init__(self, left_glob: str, right_glob: str, disp_glob: str | None = None,
                 disp_format: str | None = None):
        lefts = sorted(glob.glob(os.fspath(left_glob)))
        rights = sorted(glob.glob(os.fspath(right_glob)))
        disps = sorted(glob.glob(os.fspath(disp_glob))) if disp_glob is not None else [None] * len(lefts)
        if not (len(lefts) == len(rights) == len(disps)):
            raise ValueError(
                f"FolderPairs: {len(lefts)} left, {len(rights)} right and {len(disps)} disparity files do not pair up"
            )
        if disp_format is not None and disp_format not in _DISPARITY_READERS:
            raise ValueError(f"FolderPairs: disp_format must be one of {list(_DISPARITY_READERS)}")
        if disp_format is None and disps and disps[0] is not None:
            disp_format = _guess_disparity_format(disps[0])
        samples = [_Sample(left=left, right=right, disparity=disp) for left, right, disp in zip(lefts, rights, disps)]
        reader = _DISPARITY_READERS[disp_format] if disp_format is not None else None
        super().__init__(_require(samples, os.fspath(left_glob)), reader)
