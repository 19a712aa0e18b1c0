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
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from ..errors import ShapeError
from .metrics import MetricAccumulator, aggregate

__all__ = ["evaluate_method", "evaluate_coverages", "sgbm_rows", "mipnet_rows", "result_row", "format_table", "COVERAGES", "DEFAULT_COLUMNS"]

COVERAGES = ("full", "covered")
DEFAULT_COLUMNS = ("method", "epe", "bad1", "bad2", "bad3", "d1", "a90", "rms", "coverage", "images")


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


def evaluate_coverages(pairs: Iterable[dict], predict_fn: Callable, coverages: Sequence[str],
              on_error: Callable[[object, Exception], None] | None = None) -> dict:
    """One pass over ``pairs``, scoring every requested coverage convention (``"full"``, ``"covered"``,
    ``"dense"``): coverage -> ``per_image`` rows, their ``mean``, the ``pooled`` metrics and the ``coverage``
    percentage. A pair whose prediction raises is skipped after ``on_error(name, error)`` returns (without
    ``on_error`` the error propagates)."""
    unknown = set(coverages) - set(COVERAGES) - {"dense"}
    if unknown:
        raise ValueError(f"unknown coverage {sorted(unknown)}; expected {COVERAGES}")
    pooled = {c: MetricAccumulator() for c in coverages}
    per_image: dict[str, list] = {c: [] for c in coverages}
    gt_pixels = covered_pixels = 0
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
        gt_pixels += int(valid.sum())
        covered_pixels += int((valid & pred_valid).sum())
        for coverage in coverages:
            if coverage == "full":
                metrics = pooled[coverage].update(np.where(pred_valid, disparity, 0.0), gt, valid)
            elif coverage == "dense":  # the prediction as it is, wherever it is finite, whatever the mask says
                metrics = pooled[coverage].update(np.where(np.isfinite(disparity), disparity, 0.0), gt, valid)
            else:
                metrics = pooled[coverage].update(disparity, gt, valid & pred_valid)
            per_image[coverage].append({"name": name, **metrics})
    coverage_percent = 100.0 * covered_pixels / gt_pixels if gt_pixels else math.nan
    return {
        c: {"per_image": per_image[c], "mean": aggregate(per_image[c]), "pooled": pooled[c].compute(),
            "coverage": coverage_percent}
        for c in coverages
    }


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


def mipnet_rows(pairs: Iterable[dict], predict_fn: Callable, method: str = "MIPNet", aggregation: str = "mean",
                min_confidence: float | None = None,
                on_error: Callable[[object, Exception], None] | None = None) -> list[dict]:
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

    Returns
    -------
    list of dict
        ``[dense row]`` or ``[dense row, confident row]``.
    """
    if min_confidence is None:
        return [result_row(method, evaluate_coverages(pairs, predict_fn, ("dense",), on_error)["dense"], aggregation)]
    from .confidence import match_confidence

    def predict_with_confidence(left, right):
        disparity = predict_fn(left, right)
        return disparity, match_confidence(left, right, disparity) >= min_confidence

    results = evaluate_coverages(pairs, predict_with_confidence, ("dense", "covered"), on_error)
    dense = result_row(method, results["dense"], aggregation)
    dense["coverage"] = 100.0  # evaluate_coverages counted the confident pixels; the dense row answers at every pixel
    return [dense, result_row(f"{method} (confidence >= {min_confidence:g})", results["covered"], aggregation)]


def sgbm_rows(pairs: Iterable[dict], method: str = "SGBM", aggregation: str = "mean",
              on_error: Callable[[object, Exception], None] | None = None, **sgbm_options) -> list[dict]:
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
    **sgbm_options
        Passed to :func:`mipnet.stereo.baselines.sgbm`.

    Returns
    -------
    list of dict
        ``[full-coverage row, covered row]``; in the first, pixels SGBM left invalid count with
        disparity 0; in the second they are excluded.

    Shapes
    ------
    per pair: left, right (H, W, 3); disparity, valid (H, W).
    """
    from .baselines import sgbm

    results = evaluate_coverages(pairs, lambda left, right: sgbm(left, right, **sgbm_options), COVERAGES, on_error)
    return [
        result_row(f"{method} (full coverage)", results["full"], aggregation),
        result_row(f"{method} (covered)", results["covered"], aggregation),
    ]


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
