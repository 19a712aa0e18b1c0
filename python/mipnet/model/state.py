"""The state a MIPNet pass ends in and can start from: what a stream of video frames carries over.

A pass (docs/architecture.md §1, §2.9) runs ``n16`` iterations at the 1/16 level from an initial field (the gamma
draw, §2.4) and a hidden state pooled from ``tanh`` of the left features, hands the field over to the 1/4 level
(convex x4, §2.8) and runs ``n4`` iterations there from the hidden state ``tanh`` of the left features. A
:class:`NetworkState` holds, per level, the field and the hidden state at the end of its iterations
(:meth:`mipnet.MIPNet.forward_with_state` returns it); given back as ``init``, each piece that is set replaces its
cold start in the next pass and each piece that is None keeps it. :class:`mipnet.Stream` chooses which pieces go
from one frame to the next.

Fields are in level pixels with ``f = (f_x, f_y)``, ``f_x = -disparity`` of the level (§2.3): a full-resolution
disparity ``d`` is ``-16 f_x`` at 1/16 and ``-4 f_x`` at 1/4.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError, ShapeError

__all__ = ["NetworkState", "STATE_PIECES", "HIDDEN_CHANNELS"]

#: Channels of the update blocks' hidden state (architecture.md §2.7).
HIDDEN_CHANNELS = 128
#: The pieces of a state: name -> (channels, level divisor of the padded input size).
STATE_PIECES = {"flow16": (2, 16), "hidden16": (HIDDEN_CHANNELS, 16), "flow4": (2, 4), "hidden4": (HIDDEN_CHANNELS, 4)}


@dataclass(frozen=True)
class NetworkState:
    """The fields and hidden states of both levels at the end of a pass (or the ones a pass starts from).

    Attributes
    ----------
    flow16 : numpy.ndarray or None
        The 1/16-level field after the ``n16`` iterations (as ``init``: instead of the gamma draw).
    hidden16 : numpy.ndarray or None
        The 1/16-level hidden state after them (as ``init``: instead of the pooled ``tanh`` of the left features).
    flow4 : numpy.ndarray or None
        The 1/4-level field after the ``n4`` iterations (as ``init``: instead of the hand-over of the 1/16 field);
        None after a pass with ``n4 = 0``.
    hidden4 : numpy.ndarray or None
        The 1/4-level hidden state after them (as ``init``: instead of ``tanh`` of the left features); None after
        a pass with ``n4 = 0``.

    Shapes
    ------
    flow16: (N, 2, H/16, W/16); hidden16: (N, 128, H/16, W/16); flow4: (N, 2, H/4, W/4); hidden4: (N, 128, H/4, W/4),
    with H, W the padded input size (multiples of 16, architecture.md §2.1).
    """

    flow16: np.ndarray | None = None
    hidden16: np.ndarray | None = None
    flow4: np.ndarray | None = None
    hidden4: np.ndarray | None = None

    def select(self, names) -> "NetworkState":
        """A state keeping only the pieces ``names`` (a subset of :data:`STATE_PIECES`), the others None."""
        names = tuple(names)
        unknown = [name for name in names if name not in STATE_PIECES]
        if unknown:
            raise ArgumentError(f"NetworkState: unknown piece(s) {unknown}; the pieces are {list(STATE_PIECES)}")
        return NetworkState(**{name: getattr(self, name) for name in names})

    def disparity4(self) -> np.ndarray:
        """The 1/4-level disparity in full-resolution pixels, ``-4 f_x`` of :attr:`flow4`.

        Shapes
        ------
        return: (N, 1, H/4, W/4).
        """
        if self.flow4 is None:
            raise ArgumentError("NetworkState: no 1/4-level field (the pass ran n4 = 0 iterations at 1/4)")
        return -4.0 * self.flow4[:, 0:1]

    def check(self, batch: int, padded: tuple[int, int]) -> None:
        """ShapeError naming the piece unless every piece that is set has the shape of a batch of ``batch``
        images of the padded size ``padded`` (H, W); ArgumentError if one holds NaN or inf."""
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if value is None:
                continue
            channels, divisor = STATE_PIECES[field.name]
            # the level's size: the padded size over the level's divisor (16 or 4)
            expected = (batch, channels, padded[0] // divisor, padded[1] // divisor)
            if np.shape(value) != expected:
                raise ShapeError(f"MIPNet: init.{field.name} must have shape {list(expected)} (N, C, H/{divisor}, "
                                 f"W/{divisor} of the padded {padded[0]}x{padded[1]} input), got "
                                 f"{list(np.shape(value))}")
            if not np.all(np.isfinite(value)):
                raise ArgumentError(f"MIPNet: init.{field.name} contains NaN or inf")

    def as_dtype(self, dtype: np.dtype) -> "NetworkState":
        """The same state with every piece set as a contiguous array of ``dtype``."""
        return NetworkState(**{field.name: None if getattr(self, field.name) is None
                               else np.ascontiguousarray(getattr(self, field.name), dtype=dtype)
                               for field in dataclasses.fields(self)})
