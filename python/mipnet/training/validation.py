"""Validation during training: held-out generated pairs (pair seeds from 1,000,000 on, never used
for training) in air, turbid and low light, the natural-statistics scenes, the same scenes with their
lower rows veiled (a pale, weakly textured near region in air), and optionally a named dataset; EPE
and bad-1/2/3 pooled over valid pixels, with OpenCV SGBM on the same pairs as a reference line."""

from __future__ import annotations

import importlib.util
from typing import Callable

import numpy as np

from ..stereo.evaluation import evaluate_method, sgbm_rows
from ..data.synthetic import VALIDATION_SEED_START
from .augment import VeilParams
from ..data.registry import open_spec, parse_spec

METRICS = ("epe", "bad1", "bad2", "bad3")


class VeiledSet:
    """``dataset``'s pairs with ``veil`` applied to both views (whole images, so image row = veil row)."""

    def __init__(self, dataset, veil: VeilParams):
        self.dataset, self.veil = dataset, veil

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int) -> dict:
        sample = self.dataset[index]
        return dict(sample, left=self.veil.apply(sample["left"], 0), right=self.veil.apply(sample["right"], 0))


def lower_rows_veil(height: int) -> VeilParams:
    """The fixed veil of the ``scenes_veiled`` set: the lower 45% of the rows (where a ground plane is
    nearest) faded by 80% towards a pale warm grey, with a soft edge of a fifth of the height."""
    return VeilParams(top=0.55 * height, bottom=2.0 * height, soft=0.2 * height, strength=0.8,
                      colour=(205.0, 200.0, 195.0))


def validation_sets(size: tuple[int, int], pairs: int, extra: str | None = None) -> dict:
    """name -> dataset: ``air`` (make_pair), ``turbid``, ``low_light`` (make_pair under those
    presets), ``turbid_survey``, ``low_light_survey`` (the same scenes and water with the scene inside the
    water's visibility, as a survey flies), ``scenes`` (natural-statistics scenes), ``scenes_veiled`` (the
    same scenes under :func:`lower_rows_veil`), ``photos`` (pairs made from the held-out photographs, where
    they and scikit-image are installed), and ``extra`` (a data spec) if given."""
    from .. import data

    h, w = size
    scenes = data.SceneStereo(pairs, h, w, seed=VALIDATION_SEED_START)
    sets = {
        "air": data.SyntheticStereo(pairs, h, w, seed=VALIDATION_SEED_START),
        "turbid": data.SyntheticStereo(pairs, h, w, seed=VALIDATION_SEED_START, underwater="turbid"),
        "low_light": data.SyntheticStereo(pairs, h, w, seed=VALIDATION_SEED_START, underwater="low_light"),
        "turbid_survey": data.SyntheticStereo(pairs, h, w, seed=VALIDATION_SEED_START, underwater="turbid", survey=True),
        "low_light_survey": data.SyntheticStereo(pairs, h, w, seed=VALIDATION_SEED_START, underwater="low_light",
                                                 survey=True),
        "scenes": scenes,
        "scenes_veiled": VeiledSet(scenes, lower_rows_veil(h)),
    }
    if photo_pairs_available():
        sets["photos"] = data.PhotoStereo(pairs, h, w, seed=VALIDATION_SEED_START)
    if extra:
        spec = parse_spec(extra)
        ds = open_spec(spec, size, VALIDATION_SEED_START, pairs)
        sets[spec.name] = [ds[i] for i in range(min(pairs, len(ds)))]
    return sets


def photo_pairs_available() -> bool:
    """Whether held-out photographs and the segmentation that photo pairs need are installed."""
    from ..data import photographs

    return importlib.util.find_spec("skimage") is not None and bool(photographs.names(held_out=True))


def _summary(result: dict) -> dict:
    pooled = result["pooled"]
    return {k: float(pooled[k]) for k in METRICS}


def validate_model(predict: Callable, sets: dict) -> dict:
    """set name -> {epe, bad1, bad2, bad3} of ``predict(left, right) -> disparity``."""
    return {name: _summary(evaluate_method(iter(ds), predict)) for name, ds in sets.items()}


def validate_sgbm(sets: dict) -> dict | None:
    """The same table for OpenCV SGBM (full coverage: holes count as 0); None without OpenCV."""
    try:
        import cv2  # noqa: F401
    except ImportError:
        return None
    out = {}
    for name, ds in sets.items():
        full, _ = sgbm_rows(iter(ds), aggregation="pooled")
        out[name] = {k: float(full[k]) for k in METRICS}
    return out


def format_validation(step: int | None, table: dict, reference: dict | None = None) -> str:
    """One line per set: mipnet's metrics (and SGBM's in brackets)."""
    lines = ["validation" + (f" at step {step}:" if step is not None else ":")]
    width = max((len(name) for name in table), default=0)
    for name, m in table.items():
        ref = reference.get(name) if reference else None
        cells = [f"{k} {m[k]:.3f}" + (f" [sgbm {ref[k]:.3f}]" if ref else "") for k in METRICS]
        lines.append(f"  {name:<{width}} " + "  ".join(cells))
    return "\n".join(lines)


def mean_epe(table: dict) -> float:
    """The mean EPE over the generated sets air, turbid_survey, low_light_survey, scenes and (where present)
    photos: the number a run's best model is chosen by. The under-water sets are the survey-like ones: in
    ``turbid`` and ``low_light`` about 80% of the pixels lie where the water hides the texture, and their EPE
    there, the network's guess of a plane it cannot see, moved by 2x between checkpoints 46 steps apart while
    the survey sets moved by 4% (docs/training.md). A table without them (validated before they existed)
    takes ``turbid`` and ``low_light`` in their place. ``scenes_veiled`` is reported, not counted."""
    water = ("turbid_survey", "low_light_survey") if "turbid_survey" in table else ("turbid", "low_light")
    return float(np.mean([table[k]["epe"] for k in ("air", *water, "scenes", "photos") if k in table]))
