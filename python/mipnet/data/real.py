"""Real photographs with ground truth that ship inside packages, for evaluation only (never for
training or for choosing checkpoints and hyper-parameters).

* ``motorcycle``: the Middlebury 2014 "Motorcycle" pair (Scharstein et al., GCPR 2014), down-sampled
  4x (500x741, disparity 7-60 px, ~93% of pixels with ground truth), bundled in scikit-image
  (``skimage.data.stereo_motorcycle``; install ``scikit-image``, e.g. ``pip install ".[train]"``).
"""

from __future__ import annotations

import numpy as np

from ..errors import ArgumentError
from .datasets import Dataset
from .synthetic import apply_water

__all__ = ["RealPairs", "REAL_SETS"]

REAL_SETS = ("motorcycle",)


def _motorcycle() -> dict:
    try:
        from skimage.data import stereo_motorcycle
    except ImportError:
        raise ArgumentError("the motorcycle pair ships in scikit-image: pip install scikit-image") from None
    left, right, disparity = stereo_motorcycle()
    valid = np.isfinite(disparity) & (disparity > 0)
    return {"left": left, "right": right, "disparity": np.where(valid, disparity, 0).astype(np.float32), "valid": valid}


class RealPairs(Dataset):
    """The real pairs of ``name`` (see :data:`REAL_SETS`), optionally under synthetic water
    (``underwater``: a preset name or ``"random"``, drawn with seed ``seed``).

    Shapes
    ------
    items: left, right (H, W, 3) uint8; disparity (H, W) float32 (0 where unknown); valid (H, W) bool.
    """

    def __init__(self, name: str = "motorcycle", underwater=None, seed: int = 1_000_000):
        if name not in REAL_SETS:
            raise ArgumentError(f"RealPairs: unknown set {name!r}; choose one of {list(REAL_SETS)}")
        self.name, self.underwater, self.seed = name, underwater, seed

    def __len__(self) -> int:
        return 1

    def __getitem__(self, index: int) -> dict:
        self._check_index(index)
        pair = _motorcycle()
        label = apply_water(pair, self.underwater, self.seed)
        pair["meta"] = {"dataset": self.name, "index": 0, "underwater": label}
        return pair
