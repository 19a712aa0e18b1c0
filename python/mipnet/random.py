"""mipnet's global random state (weight init, training-mode gamma draws), seeded by ``manual_seed``."""

from __future__ import annotations

import numpy as np

__all__ = ["manual_seed", "default_generator", "log_uniform"]

_generator = np.random.default_rng()


def manual_seed(seed: int) -> np.random.Generator:
    """Reseeds the global generator (``torch.manual_seed``) and returns it."""
    global _generator
    _generator = np.random.default_rng(seed)
    return _generator


def default_generator() -> np.random.Generator:
    """The global generator."""
    return _generator


def log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """One draw from ``rng`` whose logarithm is uniform on [log low, log high]."""
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))
