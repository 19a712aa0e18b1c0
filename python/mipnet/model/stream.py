"""``Stream``: disparity for the frames of a stereo video, each frame starting from the previous frame's state.

A cold pass starts from a random disparity (the gamma draw, docs/architecture.md §2.4) and needs (6, 6) iterations;
consecutive video frames show nearly the same scene, so frame t can start from what frame t - 1 ended in
(:class:`mipnet.model.state.NetworkState`) and stop after fewer iterations. Which pieces of the state go over
(``carry``) and how many iterations a warm frame runs were measured on generated moving-camera sequences
(``scripts/stream_state.py``, docs/video.md): the default carries the previous frame's final 1/4 field (``"flow4"``),
so the 1/4 level refines the previous frame's finest answer instead of the hand-over of a short 1/16 level, and the
1/4 level's final hidden state (``"hidden4"``), which keeps the disparity from jumping between frames (less flicker,
at a slightly higher EPE than without it); then one iteration at 1/16 (whose field no longer reaches the output)
and two at 1/4.

The reset rule (docs/video.md). Before frame t runs warm, the previous disparity ``d_{t-1}`` is checked on the new
pair: ``e_new``, its photometric error on pair t (:func:`mipnet.model.photometric.photometric_error`, SSIM and L1
of the left view against the right view warped by ``d_{t-1}``; the lower quartile over the textured pixels whose
match lies inside the image, at about :data:`CHECK_WIDTH` columns), is compared with ``e_old``, the same error of ``d_{t-1}`` on its own pair t - 1. A new scene makes
``d_{t-1}`` a wrong disparity for most pixels of the new images, and the quartile jumps; the camera's motion between
two frames misplaces only the pixels near depth edges, which the quartile leaves out. If ``e_new > reset * e_old``
the frame runs cold, with ``cold_iters``, exactly as ``model(left, right, iters=cold_iters)`` would. A change of
image size always restarts cold. Under water that hides the texture (the ``turbid`` preset) every disparity
matches about as badly as any other and the rule cannot see a cut (docs/video.md); :meth:`Stream.reset` forces one.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..errors import ArgumentError, ShapeError
from .network import MIPNet, _parse_iters
from .photometric import in_image_mask, photometric_error
from .state import NetworkState

__all__ = ["Stream", "CARRY_CHOICES", "DEFAULT_CARRY", "DEFAULT_ITERS", "DEFAULT_RESET", "ERROR_QUANTILE", "CHECK_WIDTH"]

#: What a warm frame can start from, from the previous frame's final state:
#: ``flow16`` its 1/16 field; ``pooled16`` its 1/4 field, 4x4-averaged to the 1/16 level (instead of ``flow16``);
#: ``hidden16``, ``flow4``, ``hidden4`` the hidden state of the 1/16 level, the 1/4 field, the 1/4 hidden state.
CARRY_CHOICES = ("flow16", "pooled16", "hidden16", "flow4", "hidden4")
#: The measured choice (docs/video.md).
DEFAULT_CARRY = ("flow4", "hidden4")
#: Iterations (n16, n4) of a warm frame: the measured choice (docs/video.md).
DEFAULT_ITERS = (1, 2)
#: A frame restarts cold when the previous disparity's photometric error on it exceeds this times its error on its
#: own frame (docs/video.md: measured on generated sequences with and without cuts).
DEFAULT_RESET = 1.9
#: The photometric error of a disparity on a pair is this quantile of its per-pixel errors: the pixels a small camera
#: motion leaves matched, not the depth edges and occlusions it moves (docs/video.md).
ERROR_QUANTILE = 0.25
#: The reset check runs at about this many columns (docs/video.md): the frame block-averaged by W // CHECK_WIDTH.
CHECK_WIDTH = 256


def _pool16(flow4: np.ndarray) -> np.ndarray:
    """The 1/4 field averaged over 4x4 blocks to the 1/16 level, in 1/16-level pixels (a quarter of the 1/4 ones).

    Shapes
    ------
    flow4: (N, 2, 4 h, 4 w) -> (N, 2, h, w).
    """
    n, c, h4, w4 = flow4.shape
    # block (y, x) of the 1/16 level covers rows 4y..4y+3 and columns 4x..4x+3 of the 1/4 level
    return flow4.reshape(n, c, h4 // 4, 4, w4 // 4, 4).mean(axis=(3, 5)) / 4.0


def _textured(left: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels whose luminance gradient is above the frame's median, where a wrong disparity shows
    as a photometric error (on blank water or sky any disparity matches).

    Shapes
    ------
    left: (H, W, 3) -> (H, W).
    """
    luma = left @ np.array([0.299, 0.587, 0.114], np.float32)
    gradient = np.zeros(luma.shape, np.float32)
    # |I(y, x+1) - I(y, x)| + |I(y+1, x) - I(y, x)|, attributed to (y, x)
    gradient[:, :-1] += np.abs(np.diff(luma, axis=1))
    gradient[:-1] += np.abs(np.diff(luma, axis=0))
    return gradient > np.median(gradient)


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    """``a`` averaged over k x k blocks (the last rows and columns that fill no block dropped).

    Shapes
    ------
    a: (H, W, ...) -> (H // k, W // k, ...).
    """
    h, w = a.shape[0] // k * k, a.shape[1] // k * k
    # block (y, x) covers rows k y .. k y + k - 1 and columns k x .. k x + k - 1
    return a[:h, :w].reshape(h // k, k, w // k, k, *a.shape[2:]).mean(axis=(1, 3))


def _photometric(left: np.ndarray, right: np.ndarray, disp: np.ndarray) -> float:
    """The :data:`ERROR_QUANTILE` quantile of the per-pixel photometric error of ``disp`` on the pair, over the
    textured pixels (:func:`_textured`) whose match lies inside the right image (inf if none does), at about
    :data:`CHECK_WIDTH` columns: images and disparity are block-averaged by ``k = W // CHECK_WIDTH`` (the disparity
    divided by k), so a camera motion of a given share of the image moves the pixels the same at every frame size.

    Shapes
    ------
    left, right: (H, W, 3) 0..255; disp: (H, W).
    """
    k = max(1, disp.shape[1] // CHECK_WIDTH)
    if k > 1:
        left, right, disp = _block_mean(left, k), _block_mean(right, k), _block_mean(disp, k) / k
    d = np.ascontiguousarray(disp[None, None], dtype=np.float32)
    # (H, W, 3) -> (1, 3, H, W)
    error = photometric_error(left.transpose(2, 0, 1)[None], right.transpose(2, 0, 1)[None], d).numpy()
    counted = in_image_mask(d).reshape(disp.shape) & _textured(left)
    return float(np.quantile(error.reshape(disp.shape)[counted], ERROR_QUANTILE)) if counted.any() else math.inf


def _as_frame(image: Any, name: str) -> np.ndarray:
    """One frame as (H, W, 3) float32 0..255 (grey images repeated to three channels)."""
    a = np.asarray(image.numpy() if hasattr(image, "numpy") else image)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ShapeError(f"Stream: {name} must be one frame, HxWx3 or HxW, got shape {list(a.shape)}")
    return np.ascontiguousarray(np.repeat(a, 3, axis=2) if a.shape[2] == 1 else a, dtype=np.float32)


class Stream:
    """Disparity of consecutive stereo frames, each warm-started from the previous one: ``disp = stream(left, right)``.

    Parameters
    ----------
    model : MIPNet
        The network, in eval mode (e.g. ``MIPNet.pretrained()``).
    iters : (int, int), default :data:`DEFAULT_ITERS`
        Iterations (n16, n4) of a warm frame.
    cold_iters : (int, int), default (6, 6)
        Iterations of a cold frame: the first, and every frame after a reset.
    carry : sequence of str, default :data:`DEFAULT_CARRY`
        The pieces of the previous frame's state a warm frame starts from (:data:`CARRY_CHOICES`).
    reset : float or None, default :data:`DEFAULT_RESET`
        The reset threshold on the ratio of photometric errors (module docstring); None: never reset.
    seed : int, default 20
        Seed of the gamma draw of cold frames (as ``model(..., seed=seed)``).
    scale : float, default 1.0
        As ``model(..., scale=scale)``.

    Attributes
    ----------
    frames : int
        Frames run so far.
    resets : list of int
        Indices of the frames that restarted cold after a check (the first frame is not counted).
    ratios : list of float
        Per frame, ``e_new / e_old`` of the reset check (NaN where no check ran).

    Raises
    ------
    ArgumentError
        A model in training mode, bad ``iters`` / ``cold_iters``, an unknown or contradictory ``carry``, or a
        non-positive ``reset``.
    """

    def __init__(self, model: MIPNet, iters: Sequence[int] | int = DEFAULT_ITERS, *,
                 cold_iters: Sequence[int] | int = (6, 6), carry: Sequence[str] = DEFAULT_CARRY,
                 reset: float | None = DEFAULT_RESET, seed: int = 20, scale: float = 1.0):
        if not isinstance(model, MIPNet):
            raise ArgumentError(f"Stream: model must be a MIPNet, got {type(model).__name__}")
        if model.training:
            raise ArgumentError("Stream: the model is in training mode; call model.eval() first")
        self.model = model
        self.iters, self.cold_iters = _parse_iters(iters), _parse_iters(cold_iters)
        carry = tuple(carry)
        unknown = [name for name in carry if name not in CARRY_CHOICES]
        if unknown:
            raise ArgumentError(f"Stream: unknown carry {unknown}; choose from {list(CARRY_CHOICES)}")
        if "flow16" in carry and "pooled16" in carry:
            raise ArgumentError("Stream: carry flow16 or pooled16 (both set the 1/16 field), not both")
        if reset is not None and not (isinstance(reset, (int, float)) and reset > 0):  # inf: check, never reset
            raise ArgumentError(f"Stream: reset must be a positive number or None, got {reset!r}")
        self.carry, self.reset_ratio, self.seed, self.scale = carry, reset, seed, scale
        self.frames = 0
        self.resets: list[int] = []
        self.ratios: list[float] = []
        self._state: NetworkState | None = None
        self._disparity: np.ndarray | None = None
        self._error = math.nan

    def reset(self) -> None:
        """Forgets the previous frame: the next frame runs cold."""
        self._state, self._disparity, self._error = None, None, math.nan

    def __call__(self, left: Any, right: Any) -> np.ndarray:
        """The disparity of the next frame.

        Parameters
        ----------
        left, right : array_like
            One rectified frame pair, HxWx3 RGB (or HxW grey), 0..255.

        Returns
        -------
        numpy.ndarray
            (H, W) positive left-view disparity, as ``model(left, right)`` returns it.
        """
        l, r = _as_frame(left, "left"), _as_frame(right, "right")
        ratio = math.nan
        warm = self._state is not None and self._disparity.shape == l.shape[:2]
        if warm and self.reset_ratio is not None:
            ratio = _photometric(l, r, self._disparity) / max(self._error, 1e-12)
            warm = ratio <= self.reset_ratio
            if not warm:
                self.resets.append(self.frames)
        if warm:
            disp, state = self.model.forward_with_state(l, r, iters=self.iters, seed=self.seed, init=self._init(),
                                                        scale=self.scale)
        else:
            disp, state = self.model.forward_with_state(l, r, iters=self.cold_iters, seed=self.seed, scale=self.scale)
        self._state, self._disparity = state, disp
        if self.reset_ratio is not None:
            self._error = _photometric(l, r, disp)
        self.ratios.append(ratio)
        self.frames += 1
        return disp

    def _init(self) -> NetworkState:
        """The pieces of the previous state that ``carry`` names (those the previous pass did not make stay cold)."""
        state, pieces = self._state, {}
        for name in self.carry:
            if name == "pooled16":
                if state.flow4 is not None:
                    pieces["flow16"] = _pool16(state.flow4)
            elif getattr(state, name) is not None:
                pieces[name] = getattr(state, name)
        return NetworkState(**pieces)
