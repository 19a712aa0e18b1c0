"""Evaluation loops and result tables (what ``mipnet eval`` prints).

A *pair* is a dict with ``left``, ``right``, ``disparity``, ``valid`` (and optionally ``meta``),
as the datasets in :mod:`mipnet.data` yield. A *predict_fn* maps ``(left, right)`` to a disparity
map, or to ``(disparity, pred_valid)`` for methods that leave holes (SGBM).

Coverage conventions for methods with holes:

* ``"full"``: every ground-truth pixel counts; a pixel the method left invalid is scored as a
  prediction of disparity 0 (its error is the ground-truth disparity).
* ``"covered"``: only pixels the method filled are scored (the usual flattering SGBM number);
  the fraction of ground-truth pixels it filled is reported as ``coverage`` (percent).

MIPNet answers everywhere; :func:`mipnet_rows` scores its dense output and, with a confidence threshold, the
pixels whose :func:`mipnet.match_confidence` reaches it (a "covered" row beside SGBM's).

The texture-SNR split: a pair that carries ``texture_snr`` (the (H, W) map of
:func:`mipnet.underwater.texture_snr` of its clean left view, as under-water generated sets add on request) is also
scored on its pixels with texture SNR >= 1 (the water left texture a matcher can see) and < 1 (it did not: the
disparity there can only be guessed from the surroundings). ``snr_split=True`` adds those rows after each row, with
``share``, the percentage of the ground-truth pixels in the band (100 for the row over all pixels).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from ..errors import ShapeError
from .metrics import MetricAccumulator, aggregate

__all__ = ["evaluate_method", "evaluate_coverages", "sgbm_rows", "mipnet_rows", "result_row", "result_rows",
           "format_table", "COVERAGES", "DEFAULT_COLUMNS", "SNR_BANDS"]

COVERAGES = ("full", "covered")
DEFAULT_COLUMNS = ("method", "epe", "bad1", "bad2", "bad3", "d1", "a90", "rms", "coverage", "share", "images")
#: the texture-SNR bands of the split: name -> (lowest SNR, highest SNR), lower bound included
SNR_BANDS = {"texture SNR >= 1": (1.0, math.inf), "texture SNR < 1": (-math.inf, 1.0)}


def _predict(predict_fn: Callable, left, right) -> tuple[np.ndarray, np.ndarray]:
    output = predict_fn(left, right)
    if isinstance(output, tuple):
        disparity, pred_valid = output
        pred_valid = np.asarray(pred_valid, dtype=bool)
    else:
        disparity = output
        pred_valid = np.ones(np.shape(disparity), dtype=bool)
    disparity = np.asarray(disparity, dtype=np.float32)
    pred_valid = pred_valid & np.isfinite(disparity)
    return disparity, pred_valid


class _Tally:
    """The scores of one coverage convention over one set of pixels (all of them, or one SNR band)."""

    def __init__(self):
        self.pooled = MetricAccumulator()
        self.per_image: list[dict] = []
        self.gt_pixels = self.covered_pixels = 0

    def add(self, name, coverage: str, disparity: np.ndarray, pred_valid: np.ndarray, gt: np.ndarray,
            valid: np.ndarray) -> None:
        self.gt_pixels += int(valid.sum())
        self.covered_pixels += int((valid & pred_valid).sum())
        if coverage == "full":
            metrics = self.pooled.update(np.where(pred_valid, disparity, 0.0), gt, valid)
        elif coverage == "dense":  # the prediction as it is, wherever it is finite, whatever the mask says
            metrics = self.pooled.update(np.where(np.isfinite(disparity), disparity, 0.0), gt, valid)
        else:
            metrics = self.pooled.update(disparity, gt, valid & pred_valid)
        self.per_image.append({"name": name, **metrics})

    def result(self) -> dict:
        coverage_percent = 100.0 * self.covered_pixels / self.gt_pixels if self.gt_pixels else math.nan
        return {"per_image": self.per_image, "mean": aggregate(self.per_image), "pooled": self.pooled.compute(),
                "coverage": coverage_percent}


def _snr_bands(pair: dict, index: int, valid: np.ndarray) -> dict[str, np.ndarray]:
    """Band name -> the valid pixels of the band, from the pair's ``texture_snr`` map (none without one)."""
    if "texture_snr" not in pair:
        return {}
    snr = np.asarray(pair["texture_snr"], dtype=np.float64)
    if snr.shape != valid.shape:
        raise ShapeError(f"evaluate_coverages: texture_snr {snr.shape} and ground truth {valid.shape} of pair "
                         f"{index} differ")
    return {band: valid & (snr >= low) & (snr < high) for band, (low, high) in SNR_BANDS.items()}


def evaluate_coverages(pairs: Iterable[dict], predict_fn: Callable, coverages: Sequence[str],
              on_error: Callable[[object, Exception], None] | None = None) -> dict:
    """One pass over ``pairs``, scoring every requested coverage convention (``"full"``, ``"covered"``,
    ``"dense"``): coverage -> ``per_image`` rows, their ``mean``, the ``pooled`` metrics and the ``coverage``
    percentage. A pair whose prediction raises is skipped after ``on_error(name, error)`` returns (without
    ``on_error`` the error propagates).

    Where pairs carry ``texture_snr``, each coverage's result also has ``bands``: band name of
    :data:`SNR_BANDS` -> the same entries over the band's pixels of those pairs, plus ``share`` (percent of
    their ground-truth pixels in the band)."""
    unknown = set(coverages) - set(COVERAGES) - {"dense"}
    if unknown:
        raise ValueError(f"unknown coverage {sorted(unknown)}; expected {COVERAGES}")
    tallies = {c: _Tally() for c in coverages}
    band_tallies = {c: {band: _Tally() for band in SNR_BANDS} for c in coverages}
    split_pixels = 0  # ground-truth pixels of the pairs with a texture_snr map
    for index, pair in enumerate(pairs):
        meta = pair.get("meta")
        name = meta.get("left") or index if isinstance(meta, dict) else index
        try:
            disparity, pred_valid = _predict(predict_fn, pair["left"], pair["right"])
        except Exception as error:
            if on_error is None:
                raise
            on_error(name, error)
            continue
        gt = np.asarray(pair["disparity"])
        valid = np.asarray(pair["valid"], dtype=bool) & np.isfinite(gt) & (gt > 0)
        if disparity.shape != gt.shape:
            raise ShapeError(f"prediction {disparity.shape} and ground truth {gt.shape} of pair {index} differ")
        bands = _snr_bands(pair, index, valid)
        split_pixels += int(valid.sum()) if bands else 0
        for coverage in coverages:
            tallies[coverage].add(name, coverage, disparity, pred_valid, gt, valid)
            for band, in_band in bands.items():
                band_tallies[coverage][band].add(name, coverage, disparity, pred_valid, gt, in_band)
    results = {c: tallies[c].result() for c in coverages}
    if split_pixels:
        for c in coverages:
            results[c]["bands"] = {band: {**tally.result(), "share": 100.0 * tally.gt_pixels / split_pixels}
                                   for band, tally in band_tallies[c].items()}
    return results


def evaluate_method(pairs: Iterable[dict], predict_fn: Callable, coverage: str = "full",
                    on_error: Callable[[object, Exception], None] | None = None) -> dict:
    """Run ``predict_fn`` on every pair and score it.

    Parameters
    ----------
    pairs : iterable of dict
        ``left``, ``right``, ``disparity``, ``valid`` (and optional ``meta``) per pair; consumed once.
    predict_fn : callable
        ``(left, right) -> disparity`` or ``-> (disparity, pred_valid)``.
    coverage : str
        ``"full"`` (invalid predictions scored as 0) or ``"covered"`` (they are excluded).
    on_error : callable, optional
        ``(name, error)``, called when ``predict_fn`` raises on a pair; the pair is then skipped
        unless it raises. Without it the error propagates.

    Returns
    -------
    dict
        ``per_image``: list of metric dicts (plus ``name``: the left path or the index);
        ``mean``: :func:`mipnet.stereo.metrics.aggregate` of them (ETH3D style);
        ``pooled``: metrics over all pixels together (KITTI style);
        ``coverage``: percent of ground-truth pixels the method predicted.

    Shapes
    ------
    per pair: left, right (H, W, 3); disparity, valid and the prediction (H, W).
    """
    return evaluate_coverages(pairs, predict_fn, (coverage,), on_error)[coverage]


def result_row(method: str, result: dict, aggregation: str = "mean") -> dict:
    """A table row (``method`` plus metrics, ``coverage``, ``images``) from an :func:`evaluate_method` result.

    ``aggregation`` is ``"mean"`` (mean of per-image metrics) or ``"pooled"``.
    """
    if aggregation not in ("mean", "pooled"):
        raise ValueError(f"aggregation must be 'mean' or 'pooled', got {aggregation!r}")
    row = {"method": method, **result[aggregation]}
    row["coverage"] = result["coverage"]
    row["images"] = len(result["per_image"])
    return row


def result_rows(method: str, result: dict, aggregation: str = "mean", snr_split: bool = False) -> list[dict]:
    """:func:`result_row`, followed with ``snr_split`` by a row per texture-SNR band of the result (named
    ``"{method}, texture SNR >= 1"`` and ``"... < 1"``, with their ``share`` of the pixels; the first row's share
    is 100). Without bands in the result (no pair carried ``texture_snr``) it is the one row."""
    rows = [result_row(method, result, aggregation)]
    if not snr_split or "bands" not in result:
        return rows
    rows[0]["share"] = 100.0
    for band, banded in result["bands"].items():
        row = result_row(f"{method}, {band}", banded, aggregation)
        row["share"] = banded["share"]
        row["images"] = sum(1 for metrics in banded["per_image"] if metrics["n"] > 0)
        rows.append(row)
    return rows


def mipnet_rows(pairs: Iterable[dict], predict_fn: Callable, method: str = "MIPNet", aggregation: str = "mean",
                min_confidence: float | None = None,
                on_error: Callable[[object, Exception], None] | None = None, snr_split: bool = False) -> list[dict]:
    """Score a dense method, and with ``min_confidence`` also its confident pixels, in one pass.

    Parameters
    ----------
    pairs : iterable of dict
        As for :func:`evaluate_method`.
    predict_fn : callable
        ``(left, right) -> disparity`` (dense).
    method : str
        Name of the rows.
    aggregation : str
        ``"mean"`` or ``"pooled"`` (see :func:`result_row`).
    min_confidence : float, optional
        Adds a row ``"{method} (confidence >= C)"`` scored only where :func:`mipnet.match_confidence` of the
        pair and the prediction reaches C, with that share of the pixels as its ``coverage``.
    on_error : callable, optional
        As for :func:`evaluate_method`.
    snr_split : bool
        Follow each row by its texture-SNR band rows (see :func:`result_rows`).

    Returns
    -------
    list of dict
        ``[dense row]`` or ``[dense row, confident row]`` (each followed by its band rows with ``snr_split``).
    """
    if min_confidence is None:
        result = evaluate_coverages(pairs, predict_fn, ("dense",), on_error)["dense"]
        return result_rows(method, result, aggregation, snr_split)
    from .confidence import match_confidence

    def predict_with_confidence(left, right):
        disparity = predict_fn(left, right)
        return disparity, match_confidence(left, right, disparity) >= min_confidence

    results = evaluate_coverages(pairs, predict_with_confidence, ("dense", "covered"), on_error)
    dense = result_rows(method, results["dense"], aggregation, snr_split)
    for row in dense:
        row["coverage"] = 100.0  # evaluate_coverages counted the confident pixels; the dense rows answer everywhere
    confident = result_rows(f"{method} (confidence >= {min_confidence:g})", results["covered"], aggregation, snr_split)
    return dense + confident


def sgbm_rows(pairs: Iterable[dict], method: str = "SGBM", aggregation: str = "mean",
              on_error: Callable[[object, Exception], None] | None = None, snr_split: bool = False,
              **sgbm_options) -> list[dict]:
    """Score OpenCV SGBM both ways in one pass: a "full coverage" row and a "covered" row.

    Parameters
    ----------
    pairs : iterable of dict
        As for :func:`evaluate_method`.
    method : str
        Name prefix of the rows.
    aggregation : str
        ``"mean"`` or ``"pooled"`` (see :func:`result_row`).
    on_error : callable, optional
        As for :func:`evaluate_method`.
    snr_split : bool
        Follow each row by its texture-SNR band rows (see :func:`result_rows`).
    **sgbm_options
        Passed to :func:`mipnet.stereo.baselines.sgbm`.

    Returns
    -------
    list of dict
        ``[full-coverage row, covered row]``; in the first, pixels SGBM left invalid count with
        disparity 0; in the second they are excluded (each followed by its band rows with ``snr_split``).

    Shapes
    ------
    per pair: left, right (H, W, 3); disparity, valid (H, W).
    """
    from .baselines import sgbm

    results = evaluate_coverages(pairs, lambda left, right: sgbm(left, right, **sgbm_options), COVERAGES, on_error)
    return (result_rows(f"{method} (full coverage)", results["full"], aggregation, snr_split)
            + result_rows(f"{method} (covered)", results["covered"], aggregation, snr_split))


def _format_cell(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.3f}" if abs(value) < 10 else f"{value:.2f}"


def format_table(rows: Sequence[dict], columns: Sequence[str] | None = None) -> str:
    """A Markdown table of result rows (missing entries show as ``-``).

    Parameters
    ----------
    rows : sequence of dict
        E.g. from :func:`result_row` and :func:`sgbm_rows`.
    columns : sequence of str, optional
        Column keys; default :data:`DEFAULT_COLUMNS` (those present in some row).

    Returns
    -------
    str
        The table, one line per row plus a header and a separator line.

    Shapes
    ------
    not applicable.
    """
    if columns is None:
        columns = [c for c in DEFAULT_COLUMNS if any(c in row for row in rows)]
    cells = [[_format_cell(row.get(c)) for c in columns] for row in rows]
    widths = [max([len(c)] + [len(line[i]) for line in cells]) for i, c in enumerate(columns)]

    def line(values) -> str:
        # Text columns are left-aligned, numbers right-aligned.
        padded = [v.ljust(w) if c == "method" else v.rjust(w) for v, w, c in zip(values, widths, columns)]
        return "| " + " | ".join(padded) + " |"

    separator = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(columns), separator] + [line(values) for values in cells])
