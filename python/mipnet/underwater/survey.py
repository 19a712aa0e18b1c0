"""Survey geometry: the range mapping that keeps a scene inside the water's visibility, as an ROV surveys.

The image-formation model reads range from disparity, ``z = fx * baseline / d`` clipped to ``[z_min, z_max]``
(:mod:`mipnet.underwater.formation`). With the default calibration a generated scene's far surfaces lie several
metres away, beyond what turbid or dark water lets a camera see: their texture drowns in the sensor noise and no
matcher can find their disparity. A survey instead flies close enough to see its subject. :func:`survey_water`
chooses, per pair, the baseline and range clip that put the scene there:

* the visibility ``V`` (:func:`visibility`): the range at which the direct signal that carries the texture falls to
  1/e of its value at the camera, in its best channel; in daylight one attenuation length ``1 / min_c beta^D_c``,
  shorter under a lamp at the camera, whose light also falls with the square of the range;
* the farthest pixel of the scene (its smallest positive disparity) sits at ``V``, or at 5 m where the water lets
  the camera see farther (a survey flies within a few metres of its subject: its resolution falls with range);
* nothing is nearer than ``z_near = min(0.5 m, V / 2)``: nearer pixels are rendered as at ``z_near`` (with the
  ZED-like focal length a generated scene spans more depth than a survey scene, so without the clip its near
  objects would sit a few centimetres from the port).

The focal length stays the camera's, so the field of view and the spot light's cone do not change; only the water
path that a disparity means does. The disparity itself is never changed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InvalidValueError, ShapeError
from .formation import direct_signal
from .water import WaterParams

__all__ = ["visibility", "survey_water", "SURVEY_NEAR", "SURVEY_FAR"]

SURVEY_NEAR = 0.5  # m: the nearest range of a survey scene (at most half the visibility)
SURVEY_FAR = 5.0  # m: the farthest, even where the water would let the camera see farther


def visibility(water: WaterParams) -> float:
    """The water's visibility distance in m: the range at which the direct signal of a scene point
    (:func:`mipnet.underwater.formation.direct_signal`: its light times its transmission back to the camera) falls
    to 1/e of its value at the camera, in the channel that keeps it longest.

    In daylight that is one attenuation length, ``1 / min_c beta^D_c``; a spot light at the camera, whose light
    falls with the square of the range beyond 0.5 m and is attenuated on its way out too, shortens it.

    Parameters
    ----------
    water : WaterParams

    Returns
    -------
    float
    """
    target = direct_signal(water, np.zeros(1))[0] / np.e
    # The signal falls at least as fast as exp(-beta z): channel c crosses 1/e before 1 / beta_c.
    low, high = np.zeros(3), 1.0 / water.attenuation()
    for _ in range(48):  # bisection per channel: the bracket shrinks to 2^-48 of 1 / beta
        middle = (low + high) / 2
        # entry (c, c) of the (range, channel) table: channel c's signal at its own midpoint middle[c]
        above = np.diagonal(direct_signal(water, middle)) > target
        low, high = np.where(above, middle, low), np.where(above, high, middle)
    return float(high.max())


def survey_water(water: WaterParams, disparity) -> WaterParams:
    """``water`` with its range mapping fitted to one scene: the farthest pixel at the visibility distance.

    With V the smaller of :func:`visibility` of ``water`` and :data:`SURVEY_FAR` (5 m) and d_min the smallest finite
    positive disparity, the baseline becomes ``V * d_min / fx`` (fx: ``water.focal_length(W)``), so that
    ``z = fx * baseline / d`` is V at d_min and less everywhere else; ``z_max = V`` and ``z_min = min(0.5 m, V / 2)``.
    Every other parameter is ``water``'s.

    Parameters
    ----------
    water : WaterParams
        The water (its baseline, z_min and z_max are replaced).
    disparity : array_like
        The scene's left disparity in px (non-finite or <= 0: unknown, left out).

    Returns
    -------
    WaterParams

    Shapes
    ------
    disparity: (H, W).
    """
    d = np.asarray(disparity, dtype=np.float64)
    if d.ndim != 2:
        raise ShapeError(f"survey_water: expected an (H, W) disparity, got {d.shape}")
    usable = d[np.isfinite(d) & (d > 0)]
    if usable.size == 0:
        raise InvalidValueError(f"survey_water: the {d.shape} disparity has no finite positive value to fit the range to")
    far = min(visibility(water), SURVEY_FAR)
    # z = fx * baseline / d equals `far` at the smallest disparity when baseline = far * d_min / fx
    baseline = far * float(usable.min()) / water.focal_length(d.shape[1])
    return dataclasses.replace(water, baseline=baseline, z_min=min(SURVEY_NEAR, far / 2), z_max=far)
