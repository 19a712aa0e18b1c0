"""``adapt``: self-supervised fine-tuning on unlabelled rectified stereo pairs (``mipnet adapt``).

No ground truth: the loss of a step is, per training prediction ``d_i`` of the sequence (architecture.md §2.9),

    L_i = photometric(I_L, I_R warped by d_i; occlusion mask, out-of-image mask) + w_s smoothness(d_i, I_L)
    L   = sum_i gamma^(n-1-i) L_i / sum_i gamma^(n-1-i)  +  lambda sum_k (theta_k - theta0_k)^2

(:mod:`mipnet.model.photometric`: Monodepth2's ``0.85 (1 - SSIM) / 2 + 0.15 L1`` and edge-aware smoothness of the
mean-normalised disparity). ``gamma = 0`` puts the whole weight on the final prediction. The occlusion mask comes
from left-right consistency: the right view's disparity is the network run, without gradient, on the flipped,
swapped pair, ``d_R = flip(model(flip(I_R), flip(I_L)))``, and a left pixel counts only where
``|d_L(x) - d_R(x - d_L(x))| <= 1`` px for the final prediction ``d_L``. The last term (L2-SP) anchors the weights
to the ones the run started from, so the network cannot drift away from what it learnt with ground truth.
BatchNorm is frozen; AdamW without weight decay at a constant learning rate; gradients clipped to norm 1.

A run folder, resumable as ``mipnet train``'s (:mod:`mipnet.training.fit`, :mod:`mipnet.training.checkpoint`)::

    DIR/model.safetensors     the adapted weights (``mipnet.load``, ``mipnet infer --weights``); metadata
                              ``trained`` (the starting file's, then "adapted ..."), ``adapted_from``,
                              ``adapt_pairs``, ``adapt_config``, ``step``
    DIR/start.safetensors     the starting weights: the anchor theta0
    DIR/log.jsonl             one record per step: loss, photometric, smoothness, anchor, consistent, lr, ...
    DIR/config.json           the AdaptConfig
    DIR/checkpoint/           the resumable state (SIGINT / SIGTERM checkpoint after the current step)
"""

from __future__ import annotations

import dataclasses
import glob
import json
import logging
import math
import os
from typing import Any, Sequence

import numpy as np
from PIL import Image

from .._core import __version__
from ..autograd import no_grad
from ..errors import ArgumentError, FormatError, ShapeError
from ..model import pretrained
from ..model.network import MIPNet, load
from ..model.photometric import SSIM_ALPHA, lr_consistency_mask, photometric_loss, smoothness_loss
from ..optim import AdamW, clip_grad_norm_
from ..random import default_generator, manual_seed
from ..serialization import load_safetensors
from ..stereo.io import read_image
from ..tensor import Tensor
from ..utils.data.dataloader import DataLoader
from ..utils.data.dataset import Dataset
from .augment import StereoAugmentor
from .checkpoint import TrainState, list_checkpoints, load_latest_checkpoint, save_checkpoint
from .fit import Position, run_steps, save_json
from .log import TrainLog

__all__ = ["AdaptConfig", "adapt", "adapt_loss", "anchor_penalty", "right_view_disparity", "pair_files",
           "UnlabelledPairs"]

logger = logging.getLogger(__name__)

#: Settings a resumed run may change besides ``steps``: they change neither the data order nor the numbers.
RESUMABLE = ("workers", "checkpoint_every")


@dataclasses.dataclass
class AdaptConfig:
    """Every setting of an adaptation run.

    Attributes
    ----------
    left, right : list of str
        The paired image files (sorted glob matches, paired by position).
    left_glob, right_glob : str
        What the user gave (for the metadata).
    weights : str
        The starting weights (the anchor).
    steps, batch_size, crop, iters, lr :
        Target step, pairs per step, crop (H, W), (1/16, 1/4) IPM iterations while adapting, constant LR.
    anchor : float
        lambda of the L2-SP term ``lambda sum (theta - theta0)^2``.
    smoothness : float
        Weight of the edge-aware smoothness term.
    gamma : float
        Weight ``gamma^(n-1-i)`` of prediction i of n (0: the final prediction only).
    consistency : float
        Left-right consistency threshold in px.
    alpha, clip :
        SSIM's share of the photometric error; the gradient-norm clip (0: none).
    augment : bool
        Colour jitter shared by both views (no occluders, no resize, no vertical jitter).
    seed, checkpoint_every, workers :
        Seed of the data order, crops and jitter; checkpoint interval in steps; data-loading processes.
    """

    left: list
    right: list
    weights: str
    left_glob: str = ""
    right_glob: str = ""
    steps: int = 300
    batch_size: int = 2
    crop: tuple = (192, 320)
    iters: tuple = (4, 4)
    lr: float = 2e-5
    anchor: float = 1e-2
    smoothness: float = 1e-3
    gamma: float = 0.8
    consistency: float = 1.0
    alpha: float = SSIM_ALPHA
    clip: float = 1.0
    augment: bool = True
    seed: int = 1234
    checkpoint_every: int = 50
    workers: int = 1

    def __post_init__(self) -> None:
        self.crop, self.iters = tuple(int(v) for v in self.crop), tuple(int(v) for v in self.iters)
        if len(self.crop) != 2 or min(self.crop) < 32 or self.crop[0] % 16 or self.crop[1] % 16:
            raise ArgumentError(f"adapt: crop must be two multiples of 16, each >= 32, got {list(self.crop)}")
        if len(self.iters) != 2 or self.iters[0] < 1 or self.iters[1] < 0:
            raise ArgumentError(f"adapt: iters needs N16 >= 1 and N4 >= 0, got {list(self.iters)}")
        for name in ("steps", "batch_size", "checkpoint_every"):
            if int(getattr(self, name)) < 1:
                raise ArgumentError(f"adapt: {name} must be >= 1, got {getattr(self, name)}")
        for name in ("lr", "anchor", "smoothness", "gamma", "consistency", "alpha", "clip"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value >= 0):
                raise ArgumentError(f"adapt: {name} must be a finite number >= 0, got {getattr(self, name)}")
        if not self.lr > 0 or self.alpha > 1 or self.workers < 0:
            raise ArgumentError(f"adapt: needs lr > 0, alpha <= 1 and workers >= 0, got lr={self.lr} "
                                f"alpha={self.alpha} workers={self.workers}")

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


# ---- data -----------------------------------------------------------------------------------------


def _expand(files: str | Sequence[str], side: str) -> tuple[list[str], str]:
    """The files of a glob (sorted) or a list (as given), and the text that named them."""
    if isinstance(files, (str, os.PathLike)):
        pattern = os.fspath(files)
        found = sorted(glob.glob(pattern))
        if not found:
            raise ArgumentError(f"adapt: --{side} {pattern!r} matches no file")
        return found, pattern
    found = [os.fspath(f) for f in files]
    if not found:
        raise ArgumentError(f"adapt: no {side} images given")
    return found, f"{len(found)} files from {found[0]}"


def _image_size(path: str) -> tuple[int, int]:
    """(H, W) from the image header."""
    try:
        with Image.open(path) as image:
            return image.size[1], image.size[0]
    except OSError as e:
        raise FormatError(f"adapt: {path}: cannot read the image ({e})") from None


def pair_files(left: str | Sequence[str], right: str | Sequence[str]) -> tuple[list[str], list[str], str, str]:
    """Left and right files paired by position: globs sorted, lists as given. Raises ``ArgumentError`` for
    an empty glob or unequal counts and ``ShapeError`` for a pair of different sizes, naming the files.

    Returns
    -------
    lefts, rights, left_text, right_text
    """
    lefts, left_text = _expand(left, "left")
    rights, right_text = _expand(right, "right")
    if len(lefts) != len(rights):
        extra = (lefts if len(lefts) > len(rights) else rights)[min(len(lefts), len(rights))]
        raise ArgumentError(f"adapt: {len(lefts)} left images ({left_text}) but {len(rights)} right images "
                            f"({right_text}); the first without a partner: {extra}")
    for l_path, r_path in zip(lefts, rights):
        l_size, r_size = _image_size(l_path), _image_size(r_path)
        if l_size != r_size:
            raise ShapeError(f"adapt: the pair {l_path} ({l_size[0]}x{l_size[1]}, HxW) and {r_path} "
                             f"({r_size[0]}x{r_size[1]}) differ in size")
    return lefts, rights, left_text, right_text


class UnlabelledPairs(Dataset):
    """Rectified pairs without ground truth: ``{"left", "right"}`` (H, W, 3) uint8 per item."""

    def __init__(self, lefts: Sequence[str], rights: Sequence[str]):
        self.lefts, self.rights = list(lefts), list(rights)

    def __len__(self) -> int:
        return len(self.lefts)

    def __getitem__(self, index: int) -> dict:
        index = self._check_index(index)
        return {"left": read_image(self.lefts[index]), "right": read_image(self.rights[index])}


def consistent_augmentor(crop: tuple[int, int], augment: bool) -> StereoAugmentor:
    """The random crop and, with ``augment``, colour jitter drawn once for both views: nothing that would make
    the right view disagree photometrically with the left (no independent draws, occluders, y-jitter, resize
    except the upscale of images smaller than the crop)."""
    return StereoAugmentor(crop, photometric=augment, asymmetric_prob=0.0, eraser_prob=0.0, patch_prob=0.0,
                           spatial=False, yjitter=0, max_disparity=None)


def _transform(augmentor: StereoAugmentor):
    def transform(sample: dict, rng: np.random.Generator) -> dict:
        h, w = sample["left"].shape[:2]
        # the augmentor carries a disparity map along; these pairs have none
        out = augmentor({**sample, "disparity": np.zeros((h, w), np.float32), "valid": np.zeros((h, w), bool)}, rng)
        return {"left": out["left"], "right": out["right"]}

    return transform


# ---- the loss -------------------------------------------------------------------------------------


def right_view_disparity(model: MIPNet, left: np.ndarray, right: np.ndarray, iters: Sequence[int]) -> np.ndarray:
    """The right view's disparity ``flip(model(flip(right), flip(left)))``, without gradient (eval pass;
    the initial draw from mipnet's global generator, as in training).

    Shapes
    ------
    left, right (N, 3, H, W) 0..255 -> (N, 1, H, W).
    """
    training = model.training
    model.eval()
    try:
        with no_grad():
            # flip(x)[..., c] = x[..., W - 1 - c]
            disp = model(np.ascontiguousarray(right[..., ::-1]), np.ascontiguousarray(left[..., ::-1]),
                         iters=tuple(iters), seed=None)
    finally:
        model.train(training)
    return np.ascontiguousarray(disp[:, None, :, ::-1])


def anchor_penalty(model: MIPNet, reference: dict) -> Tensor:
    """``sum_k (theta_k - theta0_k)^2`` over every parameter of ``model`` (L2-SP), ``reference`` the state dict
    of theta0 (a 0-d Tensor, differentiable in the parameters).

    Shapes
    ------
    reference[name]: the shape of parameter ``name``.
    """
    total = None
    for name, p in model.named_parameters():
        if name not in reference:
            raise ArgumentError(f"anchor_penalty: the anchor has no {name} {list(p.shape)}")
        start = np.asarray(reference[name], dtype=p.dtype)
        if start.shape != p.shape:
            raise ShapeError(f"anchor_penalty: {name} is {list(p.shape)} but its anchor is {list(start.shape)}")
        diff = p - Tensor(start)
        term = (diff * diff).sum()
        total = term if total is None else total + term
    if total is None:
        raise ArgumentError("anchor_penalty: the model has no parameters")
    return total


def adapt_loss(model: MIPNet, left: np.ndarray, right: np.ndarray, iters: Sequence[int], *, gamma: float = 0.8,
               smoothness: float = 1e-3, consistency: float = 1.0, alpha: float = SSIM_ALPHA) -> tuple[Tensor, dict]:
    """The self-supervised loss of one batch (without the anchor) and its parts for the log.

    ``model`` in training mode (BatchNorm frozen). The returned dict holds ``photometric`` and ``smoothness``
    of the final prediction, and ``consistent``, the share of pixels that pass the left-right check.

    Shapes
    ------
    left, right (N, 3, H, W) 0..255 -> a 0-d Tensor, dict of floats.
    """
    preds = model(left, right, iters=tuple(iters))
    consistent = lr_consistency_mask(preds[-1].numpy(), right_view_disparity(model, left, right, iters), consistency)
    n = len(preds)
    # prediction i of n weighs gamma^(n-1-i), normalised to sum 1 (gamma = 0: the last alone)
    weights = [float(gamma) ** (n - 1 - i) for i in range(n)]
    total, parts = None, {}
    for i, (w, pred) in enumerate(zip(weights, preds)):
        if w == 0.0:
            continue
        photo = photometric_loss(left, right, pred, consistent, alpha)
        smooth = smoothness_loss(pred, left)
        term = (photo + smooth * float(smoothness)) * (w / sum(weights))
        total = term if total is None else total + term
        if i == n - 1:
            parts = {"photometric": photo.item(), "smoothness": smooth.item()}
    parts["consistent"] = float(consistent.mean())
    return total, parts


# ---- the run --------------------------------------------------------------------------------------


def _starting_weights(weights: str | None) -> str:
    if weights is None:
        if not pretrained.available():
            raise ArgumentError("adapt: this installation ships no trained weights; give --weights FILE.safetensors")
        return str(pretrained.PRETRAINED_PATH)
    if not os.path.isfile(weights):
        raise ArgumentError(f"adapt: --weights {weights}: no such file")
    return os.path.abspath(weights)


def _metadata(config: AdaptConfig, start_meta: dict, step: int) -> dict:
    """The adapted weights' metadata: the starting file's ``trained`` lineage, then this run."""
    settings = {k: v for k, v in dataclasses.asdict(config).items() if k not in ("left", "right")}
    text = (f"adapted without ground truth (mipnet adapt: photometric + left-right consistency + smoothness, "
            f"L2-SP anchor {config.anchor:g}) on {len(config.left)} pairs {config.left_glob} for {step} steps "
            f"from {config.weights}")
    previous = start_meta.get("trained")
    return {"trained": f"{previous}; then {text}" if previous else text, "adapted_from": config.weights,
            "adapt_pairs": str(len(config.left)), "adapt_config": json.dumps(settings, sort_keys=True),
            "step": str(step), "mipnet_version": __version__}


def _new_run(left, right, out: str, weights: str | None, settings: dict) -> tuple[AdaptConfig, MIPNet]:
    if list_checkpoints(out):
        raise ArgumentError(f"mipnet adapt: {out} already holds a run; continue it with --resume or choose another --out")
    if left is None or right is None:
        raise ArgumentError("adapt: needs left and right images unless resume=True")
    lefts, rights, left_text, right_text = pair_files(left, right)
    path = _starting_weights(weights)
    config = AdaptConfig(left=lefts, right=rights, weights=path, left_glob=left_text, right_glob=right_text,
                         **{k: v for k, v in settings.items() if v is not None})
    if len(lefts) < config.batch_size:
        raise ArgumentError(f"adapt: batch size {config.batch_size} needs at least as many pairs, got {len(lefts)} "
                            f"({left_text})")
    manual_seed(config.seed)
    model = load(path)
    start_meta = {k: v for k, v in load_safetensors(path)[1].items() if k not in ("format", "config")}
    model.save(os.path.join(out, "start.safetensors"), **start_meta)
    return config, model


def adapt(left_paths: str | Sequence[str] | None, right_paths: str | Sequence[str] | None, out: str,
          weights: str | None = None, *, steps: int | None = None, resume: bool = False, progress: bool = True,
          **settings: Any) -> list[dict]:
    """Adapts MIPNet to unlabelled rectified pairs without ground truth; returns the step records of this call.

    Parameters
    ----------
    left_paths, right_paths : str or list of str
        A glob of left and of right images (sorted, paired by position), or two lists of files. Ignored with
        ``resume``.
    out : str
        The run folder.
    weights : str, optional
        The weights to start from and anchor to (default: the shipped ones).
    steps : int, optional
        Adapt until this step (default ``AdaptConfig.steps``; with ``resume``, may extend the run).
    resume : bool
        Continue the run in ``out`` from its newest checkpoint (settings from it; only ``workers`` and
        ``checkpoint_every`` may change).
    progress : bool
        A progress bar on stderr.
    **settings
        Fields of :class:`AdaptConfig`: ``batch_size``, ``crop``, ``iters``, ``lr``, ``anchor``, ``smoothness``,
        ``gamma``, ``consistency``, ``alpha``, ``clip``, ``augment``, ``seed``, ``checkpoint_every``, ``workers``.
    """
    known = {f.name for f in dataclasses.fields(AdaptConfig)} - {"left", "right", "weights", "left_glob", "right_glob"}
    unknown = sorted(set(settings) - known)
    if unknown:
        raise ArgumentError(f"adapt: unknown setting(s) {unknown}; valid: {sorted(known)}")
    os.makedirs(out, exist_ok=True)
    state = None
    if resume:
        fixed = sorted(k for k, v in settings.items() if v is not None and k not in RESUMABLE)
        if fixed or weights is not None:
            raise ArgumentError(f"mipnet adapt --resume: {fixed + (['weights'] if weights else [])} cannot change in a "
                                f"resumed run (only steps and {list(RESUMABLE)})")
        state = load_latest_checkpoint(out)
        config = dataclasses.replace(AdaptConfig(**json.loads(state.config_json)),
                                     **{k: v for k, v in settings.items() if v is not None})
        model = MIPNet(**json.loads(state.model_config))
        model.load_state_dict(state.model)
    else:
        config, model = _new_run(left_paths, right_paths, out, weights, {"steps": steps, **settings})
    target = int(steps if steps is not None else config.steps)
    start_path = os.path.join(out, "start.safetensors")
    reference = load(start_path).state_dict()
    start_meta = load_safetensors(start_path)[1]

    optimizer = AdamW(model.parameters(), lr=config.lr, weight_decay=0.0, eps=1e-8)
    loader = DataLoader(UnlabelledPairs(config.left, config.right), batch_size=config.batch_size, shuffle=True,
                        drop_last=True, num_workers=config.workers, seed=config.seed,
                        transform=_transform(consistent_augmentor(config.crop, config.augment)))
    log = TrainLog(os.path.join(out, "log.jsonl"))
    position = Position()
    if state is not None:
        optimizer.load_state_dict(state.optimizer)
        default_generator().bit_generator.state = state.rng_state
        position = Position(state.step, state.epoch, state.batch)
    log.truncate_after(position.step)
    save_json(os.path.join(out, "config.json"), dataclasses.asdict(config))
    loader.set_epoch(position.epoch, position.batch)
    model.train()
    model.freeze_bn()

    def checkpoint() -> None:
        save_checkpoint(out, TrainState(step=position.step, epoch=position.epoch, batch=position.batch,
                                        model=model.state_dict(), optimizer=optimizer.state_dict(), schedule={},
                                        rng_state=default_generator().bit_generator.state, config_json=config.to_json(),
                                        model_config=model.config.to_json()))
        model.save(os.path.join(out, "model.safetensors"), **_metadata(config, start_meta, position.step))

    def adapt_step(sample: dict) -> dict:
        left, right = (sample[k].transpose(0, 3, 1, 2).astype(model.dtype) for k in ("left", "right"))
        loss, parts = adapt_loss(model, left, right, config.iters, gamma=config.gamma,
                                 smoothness=config.smoothness, consistency=config.consistency, alpha=config.alpha)
        drift = anchor_penalty(model, reference)
        if config.anchor > 0:
            loss = loss + drift * config.anchor
        optimizer.zero_grad()
        loss.backward()
        grad_norm = clip_grad_norm_(model.parameters(), config.clip) if config.clip > 0 else float("nan")
        optimizer.step()
        return {"loss": loss.item(), **parts, "anchor": config.anchor * drift.item(), "drift": drift.item(),
                "lr": config.lr, "grad_norm": grad_norm}

    return run_steps("mipnet adapt", position, target, loader, adapt_step, log=log, progress=progress,
                     periodic=[(config.checkpoint_every, checkpoint)], checkpoint=checkpoint, out=out,
                     resume_command=f"mipnet adapt --resume --out {out}",
                     postfix=lambda r: {"photo": f"{r['photometric']:.4f}"})
