"""Training configuration: ``TrainConfig``, the named presets, and how a run's settings are resolved
(preset < config file < command-line flags).

Why the ``cpu`` preset is what it is (measured with the engine of mipnet 0.1 on a 2-core Intel Xeon,
2 threads, MIPNet() from scratch): one optimisation step at 128x256, batch 4, takes 8.5 s with
(3, 3) training iterations and 16 s with (6, 6); at 384x512 batch 2 it takes 54 s. Matching begins to
emerge only after a few hundred steps, so the CPU budget buys far more learning as many small, cheap
steps: 128x256 crops, batch 4 (enough pixels for BatchNorm in the iAFF blocks and a stable loss),
(3, 3) iterations during training (the RAFT habit of training with fewer iterations than inference
uses), max LR 4e-4 with the paper's one-cycle schedule (AdamW, wd 1e-5, clip 1.0).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
from pathlib import Path
from typing import Any, Mapping

from ..errors import ArgumentError

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: the same parser as a package
    import tomli as tomllib

# Procedural training data, used when no --data is given: mostly the natural-statistics scenes
# (in air and under randomised water), some of the simple planar scenes.
DEFAULT_DATA = ("scenes:0.55", "scenes-underwater:0.3", "synthetic:0.1", "synthetic-underwater:0.05")

# Values of TrainConfig.noise_sources.
NOISE_SOURCES = ("all", "air")

#: The settings a resumed run may change (``mipnet train --resume`` / ``fit(resume=True, overrides=...)``):
#: they change neither the data order nor the numbers, only where and how often the run works and reports.
#: ``steps``, the target step, is given apart.
RESUMABLE_OVERRIDES = ("workers", "val_every", "checkpoint_every")


@dataclasses.dataclass
class TrainConfig:
    """Every setting of a training run. Defaults are the paper's first pre-training stage.

    Attributes
    ----------
    steps : int
        Train until this optimisation step.
    schedule_steps : int or None
        Length of the one-cycle schedule (its ``total_steps`` is this + 100, as RAFT-Stereo);
        None: ``steps`` of the run's first start. Fixed for the life of a run, so a resumed run
        continues the same schedule.
    batch_size, crop, iters :
        Pairs per step, crop (H, W) after augmentation, (1/16, 1/4) IPM iterations in training.
    lr, weight_decay, pct_start, clip, gamma, max_disp :
        AdamW max LR and decay, one-cycle warm-up fraction, gradient-norm clip, sequence-loss
        weight decay and the ground-truth magnitude limit (architecture.md §3.1, §3.2).
    freeze_bn : bool
        Keep BatchNorm in eval mode (fine-tuning).
    augment : bool
        Spec c.3 augmentation (photometric, eraser, scale/stretch, y-jitter); False: crop only.
    spatial_scale : (float, float)
        log2 range of the scale augmentation, s = 2 ** U(lo, hi) (RAFT-Stereo's ``--spatial_scale``;
        default its SceneFlow range (-0.2, 0.4)). Generated pairs are drawn larger than the crop
        (:data:`mipnet.training.fit.GENERATED_MARGIN`) with disparities that grow with the drawn width,
        so on them the crop already zooms in by about that margin: (-0.3, 0.1) keeps their disparities
        near those of a pair drawn at the crop's size. Ignored without ``augment``.
    veil : float
        Probability of the row veil of :class:`mipnet.training.StereoAugmentor` (``veil_prob``), a
        depth-independent fade towards a pale colour; 0 (default): off. Ignored without ``augment``.
    noise : float
        Probability of dim light and sensor noise on a training crop (``noise_prob`` of
        :class:`mipnet.training.StereoAugmentor`), independent of depth; 0 (default): off. Ignored
        without ``augment``.
    edge_weight : float
        Weight of a second loss term, the mean error over the valid pixels within
        :data:`mipnet.model.losses.EDGE_RADIUS` px of a ground-truth depth jump (``sequence_loss``'s
        ``edge_weight``); 0 (default): the plain loss.
    ema_decay : float
        Keep a moving average of the weights, avg ← d · avg + (1 − d) · θ after every step
        (:class:`mipnet.training.average.WeightAverage`), and validate and save it instead of the last
        step's weights; 0 (default): off. 0.99 averages over about the last 100 steps.
    noise_sources : str
        Which sources the noise augmentation reaches: ``"all"`` (default), or ``"air"``: every source
        but the generated under-water ones (``scenes-underwater``, ``synthetic-underwater``), whose
        renderer already draws a sensor's noise under the water's own light.
    data : list of str
        Data specs (see :mod:`mipnet.data.registry`), e.g. ``["scenes:0.7", "kitti2015:/data/kitti:0.3"]``.
    init : str or None
        Weights (``.safetensors``) to start from instead of random initialisation.
    seed : int
        Seed of the initialisation, the data order, the augmentation and the gamma draws.
    val_every, val_pairs, val_size, val_iters, val_data :
        Validate every ``val_every`` steps (0: never) on ``val_pairs`` held-out generated pairs of
        size ``val_size`` per set, at ``val_iters`` iterations; ``val_data`` optionally names a
        dataset spec to validate on as well.
    checkpoint_every : int
        Write the resumable checkpoint every this many steps (and always at the end and on SIGTERM).
    workers : int
        Data-loading worker processes (0: load in the training process).
    """

    steps: int = 100_000
    schedule_steps: int | None = None
    batch_size: int = 8
    crop: tuple[int, int] = (384, 512)
    iters: tuple[int, int] = (6, 6)
    lr: float = 6e-4
    weight_decay: float = 1e-5
    pct_start: float = 0.01
    clip: float = 1.0
    gamma: float = 0.8
    max_disp: float = 700.0
    freeze_bn: bool = False
    augment: bool = True
    spatial_scale: tuple[float, float] = (-0.2, 0.4)
    veil: float = 0.0
    noise: float = 0.0
    edge_weight: float = 0.0
    ema_decay: float = 0.0
    noise_sources: str = "all"
    data: list[str] = dataclasses.field(default_factory=lambda: list(DEFAULT_DATA))
    init: str | None = None
    seed: int = 1234
    val_every: int = 1000
    val_pairs: int = 8
    val_size: tuple[int, int] = (256, 320)
    val_iters: tuple[int, int] = (6, 6)
    val_data: str | None = None
    checkpoint_every: int = 100
    workers: int = 0

    def __post_init__(self) -> None:
        self.crop = _pair(self.crop, "crop")
        self.iters = _pair(self.iters, "iters")
        self.val_size = _pair(self.val_size, "val_size")
        self.val_iters = _pair(self.val_iters, "val_iters")
        self.spatial_scale = _range(self.spatial_scale, "spatial_scale")
        self.data = [self.data] if isinstance(self.data, str) else list(self.data)
        for name in ("steps", "batch_size", "seed", "val_every", "val_pairs", "checkpoint_every", "workers"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool):
                raise ArgumentError(f"TrainConfig: {name} must be an integer, got {value!r}")
        for name in ("lr", "weight_decay", "pct_start", "clip", "gamma", "max_disp", "veil", "noise", "edge_weight",
                     "ema_decay"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                raise ArgumentError(f"TrainConfig: {name} must be a finite number, got {value!r}")
        if not all(isinstance(d, str) for d in self.data):
            raise ArgumentError(f"TrainConfig: data must be a list of spec strings, got {self.data!r}")
        for name in ("init", "val_data"):
            if not (getattr(self, name) is None or isinstance(getattr(self, name), str)):
                raise ArgumentError(f"TrainConfig: {name} must be a string, got {getattr(self, name)!r}")
        for name in ("freeze_bn", "augment"):
            if not isinstance(getattr(self, name), bool):
                raise ArgumentError(f"TrainConfig: {name} must be true or false, got {getattr(self, name)!r}")
        if self.schedule_steps is not None and (not isinstance(self.schedule_steps, int) or isinstance(self.schedule_steps, bool)):
            raise ArgumentError(f"TrainConfig: schedule_steps must be an integer, got {self.schedule_steps!r}")
        positive = {"steps": self.steps, "batch_size": self.batch_size, "lr": self.lr, "checkpoint_every": self.checkpoint_every}
        for name, value in positive.items():
            if not value > 0:
                raise ArgumentError(f"TrainConfig: {name} must be positive, got {value}")
        if self.schedule_steps is not None and self.schedule_steps < 1:
            raise ArgumentError(f"TrainConfig: schedule_steps must be positive, got {self.schedule_steps}")
        if min(self.crop) < 32 or self.crop[0] % 16 or self.crop[1] % 16:
            raise ArgumentError(f"TrainConfig: crop must be multiples of 16 and >= 32, got {list(self.crop)}")
        if self.iters[0] < 1 or self.iters[1] < 0:
            raise ArgumentError(f"TrainConfig: iters needs N16 >= 1 and N4 >= 0, got {list(self.iters)}")
        if self.noise_sources not in NOISE_SOURCES:
            raise ArgumentError(f"TrainConfig: noise_sources must be one of {list(NOISE_SOURCES)}, got {self.noise_sources!r}")
        for name in ("veil", "noise"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ArgumentError(f"TrainConfig: {name} is a probability in [0, 1], got {getattr(self, name)}")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ArgumentError(f"TrainConfig: ema_decay must lie in [0, 1), got {self.ema_decay}")
        if self.edge_weight < 0:
            raise ArgumentError(f"TrainConfig: edge_weight must be >= 0, got {self.edge_weight}")
        if self.val_every < 0 or self.val_pairs < 0 or self.workers < 0:
            raise ArgumentError("TrainConfig: val_every, val_pairs and workers must be >= 0")
        if not self.data:
            raise ArgumentError("TrainConfig: data needs at least one spec")

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "TrainConfig":
        return cls(**json.loads(text))


def _range(value: Any, name: str) -> tuple[float, float]:
    try:
        low, high = value
    except (TypeError, ValueError):
        low = high = None
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in (low, high)) \
            or low > high:
        raise ArgumentError(f"TrainConfig: {name} must be two finite numbers (low, high) with low <= high, got {value!r}")
    return float(low), float(high)


def _pair(value: Any, name: str) -> tuple[int, int]:
    try:
        a, b = value
    except (TypeError, ValueError):
        a = b = None
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (a, b)):
        raise ArgumentError(f"TrainConfig: {name} must be two integers, got {value!r}")
    return int(a), int(b)


PRESETS: dict[str, dict[str, Any]] = {
    # Paper §4.4, stage 1: 100k steps, batch 8, 384x512, max LR 6e-4 (CREStereo data there).
    "paper-stage1": dict(steps=100_000, batch_size=8, crop=(384, 512), iters=(6, 6), lr=6e-4),
    # Stage 2: from stage 1 (--init), a new one-cycle, batch 4, 384x768, 2e-4.
    "paper-stage2": dict(steps=100_000, batch_size=4, crop=(384, 768), iters=(6, 6), lr=2e-4),
    # A 2-core CPU (see the module docstring for the measurements behind it).
    "cpu": dict(steps=20_000, batch_size=4, crop=(128, 256), iters=(3, 3), lr=4e-4, val_every=250, val_pairs=8,
                val_size=(256, 320), checkpoint_every=50, workers=1),
    # Fine-tuning on the user's data: from --init, low LR, BatchNorm frozen, a short schedule.
    "finetune": dict(steps=2_000, batch_size=2, crop=(256, 512), iters=(6, 6), lr=1e-4, freeze_bn=True,
                     val_every=250, checkpoint_every=100),
}


#: The folder of the packaged recipes: one TOML run file a stage of the campaign behind the shipped weights.
RECIPES_DIR = Path(__file__).resolve().parent / "recipes"


def recipe_names() -> list[str]:
    """The packaged recipes, by name (``mipnet train --config NAME`` takes them)."""
    return sorted((p.stem for p in RECIPES_DIR.glob("*.toml")), key=lambda s: (len(s), s))


def config_path(name_or_path: str) -> str:
    """A run file's path: ``name_or_path`` itself when it is a file, else the packaged recipe of that name."""
    if os.path.isfile(name_or_path):
        return name_or_path
    recipe = RECIPES_DIR / f"{name_or_path}.toml"
    if recipe.is_file():
        return str(recipe)
    raise ArgumentError(f"mipnet train: no config file {name_or_path!r} and no recipe of that name; "
                        f"the recipes are {recipe_names()}")


def read_config_file(path: str) -> dict[str, Any]:
    """The settings of a TOML run file or packaged recipe (keys are ``TrainConfig`` fields; ``preset = "cpu"``
    allowed)."""
    path = config_path(path)
    try:
        with open(path, "rb") as f:
            settings = tomllib.load(f)
    except OSError as e:
        raise ArgumentError(f"mipnet train: cannot read config file {path}: {e.strerror}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ArgumentError(f"mipnet train: {path} is not valid TOML: {e}") from None
    return settings


def load_config_file(path: str, preset: str | None = None, overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """``TrainConfig`` from a TOML run file (plus a preset below it and overrides above it); every
    error names the file."""
    settings = read_config_file(path)
    try:
        return resolve_config(preset, settings, overrides)
    except ArgumentError as e:
        raise ArgumentError(f"{path}: {e}") from None


def resolve_config(preset: str | None = None, file_settings: Mapping[str, Any] | None = None,
                   overrides: Mapping[str, Any] | None = None) -> TrainConfig:
    """``TrainConfig`` from a preset, then a config file's settings, then explicit overrides (None
    values in ``overrides`` mean "not given")."""
    file_settings = dict(file_settings or {})
    preset = preset or file_settings.pop("preset", None)
    file_settings.pop("preset", None)
    if preset is not None and (not isinstance(preset, str) or preset not in PRESETS):
        raise ArgumentError(f"mipnet train: unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
    settings = dict(PRESETS.get(preset, {}))
    settings.update(file_settings)
    settings.update({k: v for k, v in (overrides or {}).items() if v is not None})
    known = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(settings) - known)
    if unknown:
        raise ArgumentError(f"mipnet train: unknown setting(s) {unknown}; valid: {sorted(known)}")
    if preset == "finetune" and not settings.get("init"):
        raise ArgumentError("mipnet train: the finetune preset needs --init WEIGHTS.safetensors")
    try:
        return TrainConfig(**settings)
    except TypeError as e:
        raise ArgumentError(f"mipnet train: bad setting: {e}") from None
