"""The one registry of datasets: every name that ``mipnet train --data`` and ``mipnet eval --dataset`` take.

Three kinds of set:

* generated (no root): ``scenes`` (natural-statistics scenes, :class:`mipnet.data.SceneStereo`),
  ``scenes-underwater`` (the same under water), ``synthetic`` (the planar scenes of
  :func:`mipnet.data.make_pair`), ``synthetic-underwater``, ``photos`` (pairs made from single real
  photographs, :class:`mipnet.data.PhotoStereo`), ``photos-underwater``, and the survey-like under-water
  sets ``survey-underwater`` (the scenes of ``synthetic-underwater``) and ``scenes-survey-underwater`` (those of
  ``scenes-underwater``): the same scenes and water, with the range mapping fitted per pair so that the scene
  lies within the water's visibility (:func:`mipnet.underwater.survey_water`), as an ROV flies a survey;
* on disk, with a root folder in the official layout: ``sceneflow``, ``middlebury2014``, ``middeval3``,
  ``eth3d``, ``kitti2012``, ``kitti2015``, ``crestereo``, and ``folder`` (a folder with ``left/``,
  ``right/`` and optionally ``disp/``, files paired by sorted name);
* real evaluation pairs (:data:`mipnet.data.REAL_SETS`: ``motorcycle``, ``cones``): evaluation only,
  never training data;
* ``sequence``: generated stereo videos with a moving camera (:class:`mipnet.data.SequenceSet`, items are
  ``{"frames": [...]}``), for ``mipnet eval --dataset sequence`` only.

Training takes specs ``NAME[:ROOT][:WEIGHT]`` (``WEIGHT``, default 1, is the share of training samples
the spec contributes). Generated training pairs use pair seeds below :data:`EVAL_SEED_START` (1,000,000)
and every evaluation set starts there, so training never sees an evaluation pair.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError
from ..utils.data.dataset import Dataset
from .datasets import CREStereo, ETH3D, KITTI, FolderPairs, MiddEval3, Middlebury2014, SceneFlow
from .photo_pairs import PhotoStereo
from .real import REAL_SETS, RealPairs
from .scenes import SceneStereo
from .sequences import SequenceSet
from .synthetic import EVAL_SEED_START, SyntheticStereo

__all__ = ["DATASETS", "RegisteredDataset", "dataset_names", "open_dataset", "DataSpec", "parse_spec", "open_spec",
           "is_sparse", "renders_sensor_noise", "Mixture", "EVAL_SEED_START"]


@dataclass(frozen=True)
class RegisteredDataset:
    """One name of the registry.

    ``kind`` is ``"generated"``, ``"disk"``, ``"real"`` or ``"sequence"`` (videos, evaluation only); ``sparse``: ground truth from LiDAR or SfM points
    (the sparse augmentor); ``underwater``: generated under water, with a sensor's noise under the water's
    light; ``open``: builds the dataset from the keywords of :func:`open_dataset` it needs.
    """

    name: str
    kind: str
    open: Callable[..., Dataset]
    sparse: bool = False
    underwater: bool = False


def _generated(generator: type, underwater: bool, survey: bool = False) -> Callable[..., Dataset]:
    def open_generated(size: tuple[int, int], seed: int, count: int, water, texture_snr: bool = False,
                       **_) -> Dataset:
        h, w = size
        if not underwater:
            return generator(count, h, w, seed=seed)
        return generator(count, h, w, seed=seed, underwater=water or "random", survey=survey, texture_snr=texture_snr)
    return open_generated


def _real(name: str) -> Callable[..., Dataset]:
    def open_real(root: str | None, seed: int, water, **_) -> Dataset:
        return RealPairs(name, underwater=water, seed=seed, root=root)
    return open_real


def _sequences(size: tuple[int, int], seed: int, count: int, water, **_) -> Dataset:
    return SequenceSet(count, *size, seed=seed, water=water)


def _folder(root: str, **_) -> Dataset:
    disp = os.path.join(root, "disp")
    return FolderPairs(os.path.join(root, "left", "*"), os.path.join(root, "right", "*"),
                       os.path.join(disp, "*") if os.path.isdir(disp) else None)


_ENTRIES = [
    RegisteredDataset("scenes", "generated", _generated(SceneStereo, False)),
    RegisteredDataset("scenes-underwater", "generated", _generated(SceneStereo, True), underwater=True),
    RegisteredDataset("synthetic", "generated", _generated(SyntheticStereo, False)),
    RegisteredDataset("synthetic-underwater", "generated", _generated(SyntheticStereo, True), underwater=True),
    RegisteredDataset("photos", "generated", _generated(PhotoStereo, False)),
    RegisteredDataset("photos-underwater", "generated", _generated(PhotoStereo, True), underwater=True),
    RegisteredDataset("survey-underwater", "generated", _generated(SyntheticStereo, True, survey=True),
                      underwater=True),
    RegisteredDataset("scenes-survey-underwater", "generated", _generated(SceneStereo, True, survey=True),
                      underwater=True),
    *(RegisteredDataset(name, "real", _real(name)) for name in REAL_SETS),
    RegisteredDataset("sceneflow", "disk",
                      lambda root, split, **_: SceneFlow(root, split="TEST" if split == "test" else "TRAIN")),
    RegisteredDataset("middlebury2014", "disk", lambda root, **_: Middlebury2014(root)),
    RegisteredDataset("middeval3", "disk",
                      lambda root, resolution, **_: MiddEval3(root, split="training", resolution=resolution)),
    RegisteredDataset("eth3d", "disk", lambda root, **_: ETH3D(root, split="training"), sparse=True),
    RegisteredDataset("kitti2012", "disk", lambda root, **_: KITTI(root, year=2012), sparse=True),
    RegisteredDataset("kitti2015", "disk", lambda root, **_: KITTI(root, year=2015), sparse=True),
    RegisteredDataset("crestereo", "disk", lambda root, **_: CREStereo(root)),
    RegisteredDataset("folder", "disk", _folder),
    RegisteredDataset("sequence", "sequence", _sequences),
]

#: Every registered name -> its entry, in the order ``--help`` lists them.
DATASETS: dict[str, RegisteredDataset] = {entry.name: entry for entry in _ENTRIES}


def dataset_names(*kinds: str) -> list[str]:
    """The registered names of the given kinds (all without arguments)."""
    return [name for name, entry in DATASETS.items() if not kinds or entry.kind in kinds]


def open_dataset(name: str, *, root: str | None = None, split: str = "train", size: tuple[int, int] = (384, 512),
                 seed: int = 0, count: int = EVAL_SEED_START, water=None, resolution: str = "H",
                 texture_snr: bool = False) -> Dataset:
    """The dataset registered as ``name``.

    ``root``: the folder of an on-disk set (real sets: where ``mipnet fetch`` put them, None for the default);
    ``split``: ``"train"`` or ``"test"`` (SceneFlow's TRAIN / TEST); ``size``, ``seed``, ``count``: generated
    sets have ``count`` pairs of ``size`` (H, W) with pair seeds ``seed .. seed + count - 1``; ``water``: the
    water of under-water generated sets (a preset name or ``"random"``, the default) and of real pairs
    (None: in air); ``resolution``: MiddEval3's F, H or Q; ``texture_snr``: the pairs of under-water generated
    sets also carry ``texture_snr``, the texture SNR map of their clean left view (ignored by the other sets).
    """
    entry = DATASETS.get(name)
    if entry is None:
        raise ArgumentError(f"unknown dataset {name!r}; choose one of {list(DATASETS)}")
    if entry.kind == "disk":
        if not root:
            raise ArgumentError(f"dataset {name} needs a root folder")
        if not os.path.isdir(root):
            raise ArgumentError(f"dataset {name}: no such folder {root}")
    return entry.open(root=root, split=split, size=size, seed=seed, count=count, water=water, resolution=resolution,
                      texture_snr=texture_snr)


@dataclass(frozen=True)
class DataSpec:
    name: str
    root: str | None
    weight: float

    def __str__(self) -> str:
        return ":".join([self.name] + ([self.root] if self.root else []) + [f"{self.weight:g}"])


def parse_spec(text: str) -> DataSpec:
    """``NAME[:ROOT][:WEIGHT]`` -> DataSpec (a trailing number is the weight). Real evaluation pairs are
    not training data and are refused."""
    name, _, rest = text.partition(":")
    weight = 1.0
    head, sep, tail = rest.rpartition(":")
    candidate = tail if sep else rest
    try:
        weight = float(candidate)
        rest = head if sep else ""
    except ValueError:
        pass
    trainable = dataset_names("generated", "disk")
    if name not in trainable:
        why = " (real pairs are for evaluation only)" if name in REAL_SETS else ""
        raise ArgumentError(f"data spec {text!r}: unknown dataset {name!r}{why}; choose one of {trainable}")
    if not (weight > 0 and np.isfinite(weight)):
        raise ArgumentError(f"data spec {text!r}: the weight must be a positive number, got {weight}")
    generated = DATASETS[name].kind == "generated"
    if generated and rest:
        raise ArgumentError(f"data spec {text!r}: {name} is generated and takes no root")
    if not generated and not rest:
        raise ArgumentError(f"data spec {text!r}: {name} needs a root folder, e.g. {name}:/data/{name}")
    return DataSpec(name, rest or None, weight)


def open_spec(spec: DataSpec, size: tuple[int, int], seed: int, count: int = EVAL_SEED_START) -> Dataset:
    """The training dataset a spec names (generated under-water sets draw random water)."""
    try:
        return open_dataset(spec.name, root=spec.root, size=size, seed=seed, count=count)
    except ArgumentError as error:
        raise ArgumentError(f"data spec {spec}: {error}") from None


def is_sparse(spec: DataSpec) -> bool:
    """Whether a spec's ground truth is sparse (LiDAR / SfM points), for the sparse augmentor."""
    return DATASETS[spec.name].sparse


def renders_sensor_noise(spec: DataSpec) -> bool:
    """Whether a spec's pairs are generated under water, with a sensor's noise under the water's light
    (:func:`mipnet.underwater.degrade`)."""
    return DATASETS[spec.name].underwater


class Mixture(Dataset):
    """``length`` samples drawn from several datasets in proportion to their weights.

    Sample i comes from source k with probability w_k / Σw, chosen by a generator seeded with
    (seed, i), and from index ``h(seed, i) mod len(source)`` within it: a deterministic function of
    i, so the data order (and a resumed run) depends only on the loader's seed and position.
    """

    def __init__(self, sources: list[Dataset], weights: list[float], length: int, seed: int = 0):
        if not sources or len(sources) != len(weights):
            raise ArgumentError("Mixture: needs one weight per source and at least one source")
        empty = [i for i, s in enumerate(sources) if len(s) == 0]
        if empty:
            raise ArgumentError(f"Mixture: source(s) {empty} are empty")
        self.sources, self.length, self.seed = sources, int(length), seed
        w = np.asarray(weights, dtype=np.float64)
        self.cumulative = np.cumsum(w / w.sum())

    def __len__(self) -> int:
        return self.length

    def source_of(self, index: int) -> tuple[int, int]:
        """(source number, index within it) of sample ``index``."""
        rng = np.random.default_rng([self.seed, int(index)])
        # the first k with u < cumulative[k], u ~ U[0, 1)
        k = min(int(np.searchsorted(self.cumulative, rng.random(), side="right")), len(self.sources) - 1)
        return k, int(rng.integers(0, len(self.sources[k])))

    def __getitem__(self, index: int) -> dict:
        k, inner = self.source_of(self._check_index(index))
        sample = self.sources[k][inner]
        sample["source"] = k
        return sample
