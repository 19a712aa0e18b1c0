"""Water: the parameters of the image-formation model, its presets and random draws around them."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import ArgumentError
from ..random import log_uniform

__all__ = ["WaterParams", "PRESETS", "JERLOV_KD", "random_water", "resolve_params", "REFERENCE_FX", "REFERENCE_WIDTH"]

REFERENCE_WIDTH = 1280.0  # ZED-like default calibration: fx = 700 px at 1280 px width, scaled with the width
REFERENCE_FX = 700.0

# Jerlov diffuse attenuation K_d (1/m) at 650 nm (R), 550 nm (G), 450 nm (B).
JERLOV_KD: dict[str, tuple[float, float, float]] = {
    "I": (0.36, 0.063, 0.019),
    "IA": (0.37, 0.067, 0.026),
    "IB": (0.376, 0.072, 0.036),
    "II": (0.40, 0.089, 0.068),
    "III": (0.445, 0.12, 0.136),
    "1C": (0.45, 0.12, 0.25),
    "3C": (0.46, 0.19, 0.39),
    "5C": (0.54, 0.30, 0.56),
    "7C": (0.63, 0.46, 0.89),
    "9C": (0.76, 0.63, 1.6),
}


@dataclass(frozen=True)
class WaterParams:
    """Parameters of :func:`degrade` (see the module docstring for the model).

    Attributes
    ----------
    water_type : str
        Jerlov class (``I, IA, IB, II, III, 1C, 3C, 5C, 7C, 9C``).
    scattering : float
        Spectrally flat extra attenuation of the direct signal (1/m).
    backscatter_coef : tuple of 3 float
        beta^B (R, G, B) in 1/m.
    veiling_light : tuple of 3 float
        B_inf (R, G, B), linear, at the surface.
    backscatter_strength : float
        Multiplier on the backscatter term.
    forward_scatter : float
        Blur sigma in px per metre of range, for a 1280 px wide image (scaled with width).
    depth : float
        Camera depth below the surface (m).
    gain : float
        Exposure gain after auto-exposure (< 1: low light).
    full_well : float
        Photo-electrons at full scale (Poisson noise; smaller = noisier).
    read_noise : float
        Gaussian read-noise std as a fraction of full scale.
    artificial_light : float
        Strength of a spot light at the camera, relative to surface daylight (0: none).
    light_cone : float
        Spot radius (1/e) as a fraction of the image diagonal.
    marine_snow : float
        Particles per megapixel.
    snow_brightness : float
        Peak brightness of a particle (fraction of full scale, before ``gain``).
    fx : float or None
        Focal length in px; None: 700 px scaled by width / 1280.
    baseline : float
        Stereo baseline (m).
    z_min, z_max : float
        Range clip (m).
    """

    water_type: str = "3C"
    scattering: float = 0.15
    backscatter_coef: tuple = (0.25, 0.3, 0.3)
    veiling_light: tuple = (0.10, 0.45, 0.35)
    backscatter_strength: float = 1.0
    forward_scatter: float = 0.4
    depth: float = 5.0
    gain: float = 1.0
    full_well: float = 1000.0
    read_noise: float = 0.003
    artificial_light: float = 0.0
    light_cone: float = 0.5
    marine_snow: float = 60.0
    snow_brightness: float = 0.6
    fx: float | None = None
    baseline: float = 0.12
    z_min: float = 0.3
    z_max: float = 20.0

    def __post_init__(self):
        if self.water_type not in JERLOV_KD:
            raise ValueError(f"unknown Jerlov water type {self.water_type!r}; expected one of {list(JERLOV_KD)}")
        if not 0 < self.z_min < self.z_max:
            raise ValueError(f"need 0 < z_min < z_max, got {self.z_min}, {self.z_max}")
        if self.full_well <= 0 or self.read_noise < 0 or self.gain <= 0:
            raise ValueError("full_well and gain must be positive, read_noise non-negative")

    def focal_length(self, width: int) -> float:
        """Focal length in px for an image ``width`` px wide: ``fx``, or 700 px scaled by width / 1280."""
        return self.fx if self.fx is not None else REFERENCE_FX * width / REFERENCE_WIDTH

    def attenuation(self) -> np.ndarray:
        """beta^D (R, G, B) in 1/m: Jerlov's K_d of ``water_type`` plus the flat ``scattering``."""
        return np.asarray(JERLOV_KD[self.water_type], dtype=np.float64) + self.scattering


PRESETS: dict[str, WaterParams] = {
    "clear": WaterParams(
        water_type="I", scattering=0.03, backscatter_coef=(0.05, 0.06, 0.08),
        veiling_light=(0.05, 0.30, 0.55), forward_scatter=0.15, depth=3.0,
        full_well=2000.0, read_noise=0.002, marine_snow=10.0,
    ),
    "coastal": WaterParams(),
    "turbid": WaterParams(
        water_type="9C", scattering=0.6, backscatter_coef=(0.9, 0.9, 0.8),
        veiling_light=(0.30, 0.45, 0.30), forward_scatter=1.2, depth=2.0,
        full_well=800.0, read_noise=0.004, marine_snow=250.0,
    ),
    "low_light": WaterParams(
        water_type="5C", scattering=0.2, backscatter_coef=(0.3, 0.35, 0.3),
        veiling_light=(0.08, 0.35, 0.30), forward_scatter=0.5, depth=20.0, gain=0.15,
        full_well=300.0, read_noise=0.01, artificial_light=1.5, marine_snow=120.0, snow_brightness=1.0,
    ),
}


def random_water(rng: np.random.Generator, preset: str | None = None) -> WaterParams:
    """Water drawn around a preset: the preset (``preset``, or one of :data:`PRESETS` drawn
    uniformly), then every parameter jittered independently within a physically plausible range.

    With p the base preset's value and logU(lo, hi) a log-uniform factor:

    ==========================  =============================================================
    water_type                  p's Jerlov class, or (probability 1/2) its neighbour in the
                                order I, IA, IB, II, III, 1C, 3C, 5C, 7C, 9C
    scattering                  p * logU(0.5, 2), within [0.005, 1.5] 1/m
    backscatter_coef            p * logU(0.6, 1.7) * U(0.85, 1.15) per channel, within [0.01, 2] 1/m
    veiling_light               p * U(0.7, 1.35) per channel, within [0.01, 0.9]
    backscatter_strength        p * U(0.6, 1.4)
    forward_scatter             p * logU(0.5, 2), at most 2.5 px/m
    depth                       p * logU(0.5, 2), within [0.5, 40] m
    gain                        p * logU(0.67, 1.5), within [0.05, 1.5]
    full_well                   p * logU(0.5, 2), within [100, 5000] electrons
    read_noise                  p * logU(0.5, 2), within [0.0005, 0.03]
    artificial_light            p * U(0.6, 1.5) if p > 0; else U(0.2, 1) with probability 0.15
                                (a dive light in daylight), otherwise 0
    light_cone                  U(0.3, 0.8)
    marine_snow                 p * logU(0.3, 3), at most 1000 per megapixel
    snow_brightness             p * U(0.6, 1.3), within [0.1, 1.2]
    baseline                    p * logU(0.5, 2) (0.06-0.24 m for the presets: sets the range
                                that a disparity means, i.e. the water path)
    fx, z_min, z_max            p
    ==========================  =============================================================

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of every draw; the result is a deterministic function of its state and ``preset``.
    preset : str, optional
        Name in :data:`PRESETS`; None draws one.

    Returns
    -------
    WaterParams
    """
    if not isinstance(rng, np.random.Generator):
        raise ArgumentError(f"random_water: rng must be a numpy.random.Generator, got {type(rng).__name__}")
    names = list(PRESETS)
    pick = names[int(rng.integers(len(names)))]  # drawn even when preset is given: same draws after it
    if preset is not None and preset not in PRESETS:
        raise ArgumentError(f"random_water: unknown preset {preset!r}; expected one of {names} or None")
    base = PRESETS[preset if preset is not None else pick]

    classes = list(JERLOV_KD)
    position = classes.index(base.water_type)
    # Half the time a neighbouring class, one step either way (clamped to the list's ends).
    step = int(rng.choice([-1, 1])) if rng.random() < 0.5 else 0
    water_type = classes[int(np.clip(position + step, 0, len(classes) - 1))]
    backscatter = np.clip(np.asarray(base.backscatter_coef) * log_uniform(rng, 0.6, 1.7) * rng.uniform(0.85, 1.15, 3), 0.01, 2.0)
    veil = np.clip(np.asarray(base.veiling_light) * rng.uniform(0.7, 1.35, 3), 0.01, 0.9)
    lamp_draw, lamp_strength, lamp_scale = rng.random(), rng.uniform(0.2, 1.0), rng.uniform(0.6, 1.5)
    if base.artificial_light > 0:
        light = base.artificial_light * lamp_scale
    else:
        light = lamp_strength if lamp_draw < 0.15 else 0.0
    return dataclasses.replace(
        base,
        water_type=water_type,
        scattering=float(np.clip(base.scattering * log_uniform(rng, 0.5, 2.0), 0.005, 1.5)),
        backscatter_coef=tuple(float(v) for v in backscatter),
        veiling_light=tuple(float(v) for v in veil),
        backscatter_strength=float(base.backscatter_strength * rng.uniform(0.6, 1.4)),
        forward_scatter=float(min(base.forward_scatter * log_uniform(rng, 0.5, 2.0), 2.5)),
        depth=float(np.clip(base.depth * log_uniform(rng, 0.5, 2.0), 0.5, 40.0)),
        gain=float(np.clip(base.gain * log_uniform(rng, 0.67, 1.5), 0.05, 1.5)),
        full_well=float(np.clip(base.full_well * log_uniform(rng, 0.5, 2.0), 100.0, 5000.0)),
        read_noise=float(np.clip(base.read_noise * log_uniform(rng, 0.5, 2.0), 0.0005, 0.03)),
        artificial_light=float(light),
        light_cone=float(rng.uniform(0.3, 0.8)),
        marine_snow=float(min(base.marine_snow * log_uniform(rng, 0.3, 3.0), 1000.0)),
        snow_brightness=float(np.clip(base.snow_brightness * rng.uniform(0.6, 1.3), 0.1, 1.2)),
        baseline=float(base.baseline * log_uniform(rng, 0.5, 2.0)),
    )


def resolve_params(preset, overrides: Mapping) -> WaterParams:
    if isinstance(preset, WaterParams):
        base = preset
    elif preset in PRESETS:
        base = PRESETS[preset]
    else:
        raise ValueError(f"unknown underwater preset {preset!r}; expected one of {list(PRESETS)} or a WaterParams")
    known = {f.name for f in dataclasses.fields(WaterParams)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise TypeError(f"unknown water parameter(s) {unknown}; valid: {sorted(known)}")
    return dataclasses.replace(base, **overrides)
