"""Training data from spec strings, as ``mipnet train --data`` takes them.

A spec is ``NAME[:ROOT][:WEIGHT]``:

* generated (no root): ``scenes`` (natural-statistics scenes, :class:`mipnet.data.SceneStereo`),
  ``scenes-underwater`` (the same under randomised water), ``synthetic`` (the planar scenes of
  :func:`mipnet.data.make_pair`), ``synthetic-underwater``;
* on disk: ``sceneflow``, ``middlebury2014``, ``middeval3``, ``eth3d``, ``kitti2012``,
  ``kitti2015``, ``crestereo`` with ``:ROOT`` in the official layout, and ``folder:ROOT`` for a
  folder with ``left/``, ``right/`` and optionally ``disp/`` (files paired by sorted name);
* ``WEIGHT`` (a number, default 1) is the share of training samples the spec contributes.

Generated training pairs use pair seeds below :data:`EVAL_SEED_START` (1,000,000) and every
evaluation set starts there, so training never sees an evaluation pair.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .. import data
from ..data.datasets import Dataset
from ..data.synthetic import EVAL_SEED_START
from ..errors import ArgumentError

GENERATED = ("scenes", "scenes-underwater", "synthetic", "synthetic-underwater")
ON_DISK = ("sceneflow", "middlebury2014", "middeval3", "eth3d", "kitti2012", "kitti2015", "crestereo", "folder")


@dataclass(frozen=True)
class DataSpec:
    name: str
    root: str | None
    weight: float

    def __str__(self) -> str:
        return ":".join([self.name] + ([self.root] if self.root else []) + [f"{self.weight:g}"])


def parse_spec(text: str) -> DataSpec:
    """``NAME[:ROOT][:WEIGHT]`` -> DataSpec (a trailing number is the weight)."""
    name, _, rest = text.partition(":")
    weight = 1.0
    head, sep, tail = rest.rpartition(":")
    candidate = tail if sep else rest
    try:
        weight = float(candidate)
        rest = head if sep else ""
    except ValueError:
        pass
    if name not in GENERATED + ON_DISK:
        raise ArgumentError(f"data spec {text!r}: unknown dataset {name!r}; choose one of {list(GENERATED + ON_DISK)}")
    if not (weight > 0 and np.isfinite(weight)):
        raise ArgumentError(f"data spec {text!r}: the weight must be a positive number, got {weight}")
    if name in GENERATED and rest:
        raise ArgumentError(f"data spec {text!r}: {name} is generated and takes no root")
    if name in ON_DISK and not rest:
        raise ArgumentError(f"data spec {text!r}: {name} needs a root folder, e.g. {name}:/data/{name}")
    return DataSpec(name, rest or None, weight)


def open_spec(spec: DataSpec, size: tuple[int, int], seed: int, count: int = EVAL_SEED_START) -> Dataset:
    """The dataset a spec names. Generated sets have ``count`` pairs of ``size`` (H, W) with pair
    seeds ``seed .. seed + count - 1``."""
    h, w = size
    if spec.name == "scenes":
        return data.SceneStereo(count, h, w, seed=seed)
    if spec.name == "scenes-underwater":
        return data.SceneStereo(count, h, w, seed=seed, underwater="random")
    if spec.name == "synthetic":
        return data.SyntheticStereo(count, h, w, seed=seed)
    if spec.name == "synthetic-underwater":
        return data.SyntheticStereo(count, h, w, seed=seed, underwater="random")
    root = spec.root
    if not os.path.isdir(root):
        raise ArgumentError(f"data spec {spec}: no such folder {root}")
    if spec.name == "folder":
        disp = os.path.join(root, "disp", "*")
        return data.FolderPairs(os.path.join(root, "left", "*"), os.path.join(root, "right", "*"),
                                disp if os.path.isdir(os.path.join(root, "disp")) else None)
    return {
        "sceneflow": lambda: data.SceneFlow(root, split="TRAIN"),
        "middlebury2014": lambda: data.Middlebury2014(root),
        "middeval3": lambda: data.MiddEval3(root, split="training", resolution="H"),
        "eth3d": lambda: data.ETH3D(root, split="training"),
        "kitti2012": lambda: data.KITTI(root, year=2012),
        "kitti2015": lambda: data.KITTI(root, year=2015),
        "crestereo": lambda: data.CREStereo(root),
    }[spec.name]()


def is_sparse(spec: DataSpec) -> bool:
    """Whether a spec's ground truth is sparse (LiDAR / SfM points), for the sparse augmentor."""
    return spec.name in ("kitti2012", "kitti2015", "eth3d")


def renders_sensor_noise(spec: DataSpec) -> bool:
    """Whether a spec's pairs are generated under water, with a sensor's noise under the water's light
    (:func:`mipnet.underwater.degrade`)."""
    return spec.name in ("scenes-underwater", "synthetic-underwater")


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
