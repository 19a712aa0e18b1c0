"""Training MIPNet: ``fit`` (the loop behind ``mipnet train``), ``adapt`` (self-supervised fine-tuning on
unlabelled pairs, ``mipnet adapt``), presets, augmentation, checkpoints, logs and plots.

    from mipnet.training import fit, resolve_config
    fit(resolve_config("cpu", overrides={"steps": 300}), "runs/cpu")
    fit(None, "runs/cpu", resume=True, steps=600)
"""

from .augment import SparseStereoAugmentor, StereoAugmentor, make_augmentor
from .checkpoint import load_latest_checkpoint
from .config import PRESETS, TrainConfig, resolve_config
from ..data.registry import EVAL_SEED_START, Mixture, parse_spec
from .fit import fit
from .adapt import adapt
from .plot import plot

__all__ = ["fit", "adapt", "TrainConfig", "PRESETS", "resolve_config", "StereoAugmentor", "SparseStereoAugmentor",
           "make_augmentor", "Mixture", "parse_spec", "EVAL_SEED_START", "load_latest_checkpoint", "plot"]
