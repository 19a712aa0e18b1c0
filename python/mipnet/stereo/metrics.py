"""Stereo evaluation metrics (ETH3D / Middlebury / KITTI conventions).

With ``e = |pred - gt|`` over the evaluated pixels ``V`` (given mask AND finite gt AND gt > 0):

* ``epe``: mean(e) (ETH3D/Middlebury "avgerr");
* ``bad<t>``: percentage of V with ``e > t`` for t in 0.5, 1, 2, 3, 4, 5, 7;
* ``a50, a90, a95, a99``: quantiles of e (``np.percentile``, linear interpolation);
* ``rms``: sqrt(mean(e^2));
* ``d1``: KITTI 2015 outliers, percentage with ``e > 3`` AND ``e > 0.05 * gt``;
* ``n``: |V|.

A non-finite prediction at an evaluated pixel is scored as a prediction of 0 (error = gt), so
missing predictions count as errors rather than disappearing from the average. With no evaluated
pixel every metric is ``nan`` and ``n`` is 0.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from ..errors import ShapeError

__all__ = ["evaluate", "aggregate", "MetricAccumulator", "THRESHOLDS", "QUANTILES", "METRIC_KEYS"]

THRESHOLDS = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 7.0)
QUANTILES = (50, 90, 95, 99)
_BAD_KEYS = tuple(f"bad{t:g}" for t in THRESHOLDS)
_QUANTILE_KEYS = tuple(f"a{q}" for q in QUANTILES)
METRIC_KEYS = ("epe",) + _BAD_KEYS + _QUANTILE_KEYS + ("rms", "d1")


def _errors(pred, gt, valid) -> tuple[np.ndarray, np.ndarray]:
    """Absolute errors and ground truth at the evaluated pixels (1-D float64 arrays)."""
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ShapeError(f"metrics: prediction shape {pred.shape} does not match ground truth shape {gt.shape}")
    mask = np.isfinite(gt) & (gt > 0)
    if valid is not None:
        valid = np.asarray(valid)
        if valid.shape != gt.shape:
            raise ShapeError(f"metrics: valid-mask shape {valid.shape} does not match ground truth shape {gt.shape}")
        mask &= valid.astype(bool)
    gt_v = gt[mask]
    pred_v = pred[mask]
    pred_v = np.where(np.isfinite(pred_v), pred_v, 0.0)
    return np.abs(pred_v - gt_v), gt_v


class MetricAccumulator:
    """Pools errors over all pixels of many images (KITTI / SceneFlow style "pooled" metrics).

    Sums are kept in float64; for exact pooled quantiles every error is kept (4 bytes per
    evaluated pixel, as float32). Pass ``quantiles=False`` to keep only the sums; the ``a*``
    entries are then ``nan``.

    Examples
    --------
    >>> acc = MetricAccumulator()
    >>> for pred, gt, valid in results:          # doctest: +SKIP
    ...     per_image = acc.update(pred, gt, valid)
    >>> pooled = acc.compute()                   # doctest: +SKIP
    """

    def __init__(self, quantiles: bool = True):
        self.quantiles = quantiles
        self.reset()

    def reset(self) -> None:
        """Forget everything accumulated so far."""
        self.n = 0
        self._sum = 0.0
        self._sum_sq = 0.0
        self._bad = np.zeros(len(THRESHOLDS), dtype=np.int64)
        self._d1 = 0
        self._chunks: list[np.ndarray] = []

    def update(self, pred, gt, valid=None) -> dict:
        """Add one image; returns that image's own metrics (see :func:`evaluate`).

        Shapes
        ------
        pred, gt, valid: (H, W) (any equal shapes).
        """
        e, gt_v = _errors(pred, gt, valid)
        self._add(e, gt_v)
        return _summary(*_counts(e, gt_v), e if self.quantiles else None)

    def _add(self, e: np.ndarray, gt_v: np.ndarray) -> None:
        n, total, total_sq, bad, d1 = _counts(e, gt_v)
        self.n += n
        self._sum += total
        self._sum_sq += total_sq
        self._bad += bad
        self._d1 += d1
        if self.quantiles:
            self._chunks.append(e.astype(np.float32))

    def compute(self) -> dict:
        """Metrics pooled over every pixel added so far (same keys as :func:`evaluate`)."""
        errors = None
        if self.quantiles:
            errors = np.concatenate(self._chunks) if self._chunks else np.zeros(0, np.float32)
        return _summary(self.n, self._sum, self._sum_sq, self._bad, self._d1, errors)


def _counts(e: np.ndarray, gt_v: np.ndarray) -> tuple[int, float, float, np.ndarray, int]:
    bad = np.array([np.count_nonzero(e > t) for t in THRESHOLDS], dtype=np.int64)
    d1 = int(np.count_nonzero((e > 3.0) & (e > 0.05 * gt_v)))
    return int(e.size), float(e.sum()), float(np.square(e).sum()), bad, d1


def _summary(n: int, total: float, total_sq: float, bad: np.ndarray, d1: int, errors) -> dict:
    if n == 0:
        result = {key: math.nan for key in METRIC_KEYS}
        result["n"] = 0
        return result
    result = {"epe": total / n}
    result.update({key: 100.0 * float(count) / n for key, count in zip(_BAD_KEYS, bad)})
    if errors is None:
        result.update({key: math.nan for key in _QUANTILE_KEYS})
    else:
        values = np.percentile(errors.astype(np.float64), QUANTILES)
        result.update({key: float(v) for key, v in zip(_QUANTILE_KEYS, values)})
    result["rms"] = math.sqrt(total_sq / n)
    result["d1"] = 100.0 * d1 / n
    result["n"] = n
    return result


def evaluate(pred, gt, valid=None) -> dict:
    """Metrics of one disparity prediction against ground truth.

    Parameters
    ----------
    pred : array_like
        Predicted disparity (px); non-finite values count as 0.
    gt : array_like
        Ground-truth disparity (px); non-finite or non-positive values are not evaluated.
    valid : array_like of bool, optional
        Extra evaluation mask (e.g. non-occluded pixels).

    Returns
    -------
    dict
        ``epe, bad0.5, bad1, bad2, bad3, bad4, bad5, bad7, a50, a90, a95, a99, rms, d1`` (floats;
        ``bad*`` and ``d1`` in percent) and ``n`` (int, evaluated pixels).

    Shapes
    ------
    pred, gt, valid: (H, W) (any equal shapes).

    Raises
    ------
    ShapeError
        The shapes differ.
    """
    e, gt_v = _errors(pred, gt, valid)
    return _summary(*_counts(e, gt_v), e)


def aggregate(results: Iterable[Mapping], mode: str = "mean") -> dict:
    """Combine per-image metric dicts into one (ETH3D style: the plain mean of per-image values).

    Images with ``n == 0`` (nothing evaluated) are left out of the mean. For metrics pooled over
    all pixels (KITTI / SceneFlow style, exact pooled quantiles) use :class:`MetricAccumulator`.

    Parameters
    ----------
    results : iterable of dict
        Outputs of :func:`evaluate`.
    mode : str
        ``"mean"`` (the only mode; explicit so calling code documents its choice).

    Returns
    -------
    dict
        Same metric keys, plus ``n`` (total evaluated pixels) and ``images`` (images averaged).

    Shapes
    ------
    scalars only.
    """
    if mode != "mean":
        raise ValueError(f"aggregate: unknown mode {mode!r}; use 'mean' (pooled: MetricAccumulator)")
    used = [r for r in results if r.get("n", 0) > 0]
    result = {key: float(np.mean([r[key] for r in used])) if used else math.nan for key in METRIC_KEYS}
    result["n"] = int(sum(r["n"] for r in used))
    result["images"] = len(used)
    return result
