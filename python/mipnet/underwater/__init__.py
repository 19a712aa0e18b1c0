"""Under-water image formation: turn an in-air stereo pair into the pair a camera under water would see.

* :mod:`~mipnet.underwater.water` — the water's parameters (:class:`WaterParams`), the named presets and
  random draws around them;
* :mod:`~mipnet.underwater.color` — sRGB <-> linear RGB, the space the model works in;
* :mod:`~mipnet.underwater.formation` — :func:`degrade` (the image-formation model) and
  :func:`texture_snr` (where the water leaves texture a matcher can see);
* :mod:`~mipnet.underwater.survey` — :func:`visibility` and :func:`survey_water` (the range mapping that keeps a
  scene inside the water's visibility, as a survey does).
"""

from .color import linear_to_srgb, srgb_to_linear
from .formation import degrade, texture_snr
from .survey import survey_water, visibility
from .water import JERLOV_KD, PRESETS, WaterParams, random_water

__all__ = ["degrade", "texture_snr", "random_water", "WaterParams", "PRESETS", "JERLOV_KD", "srgb_to_linear",
           "linear_to_srgb", "survey_water", "visibility"]
