"""The stereo pair bundled with the package: what ``mipnet infer`` runs when it is given no images.

A 240x320 procedural pair (``make_pair(240, 320, seed=7)``) under the ``coastal`` water preset, with its exact
ground-truth disparity; never a training pair (python/mipnet/assets/README.md says how it was made).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..stereo.io import read_image, read_pfm

__all__ = ["EXAMPLE_LEFT", "EXAMPLE_RIGHT", "EXAMPLE_DISPARITY", "example_pair"]

_ASSETS = Path(__file__).resolve().parents[1] / "assets"
EXAMPLE_LEFT = _ASSETS / "example_left.png"
EXAMPLE_RIGHT = _ASSETS / "example_right.png"
EXAMPLE_DISPARITY = _ASSETS / "example_disp.pfm"


def example_pair() -> dict:
    """The bundled pair as a dataset sample: ``left``, ``right`` (HxWx3 uint8 RGB), ``disparity`` (HxW float32)
    and ``valid`` (HxW bool: finite, positive ground truth)."""
    disparity = read_pfm(EXAMPLE_DISPARITY)
    return {"left": read_image(EXAMPLE_LEFT), "right": read_image(EXAMPLE_RIGHT), "disparity": disparity,
            "valid": np.isfinite(disparity) & (disparity > 0)}
