"""Temporal metrics of a disparity video: per-frame scores and flicker through known correspondences.

Flicker of frame t (docs/video.md): ``F_t = mean |d_t(x) - d_{t-1}(x_{t-1}(x))|`` over the pixels whose point is
visible in frames t - 1 and t, where ``x_{t-1}(x)`` is the position in frame t - 1 of the point that pixel ``x`` of
frame t shows (on the same row: the generated sequences' rig moves along its baseline, :mod:`mipnet.data.sequences`)
and ``d_{t-1}`` is read there by linear interpolation along the row. The ground truth's own ``F_t``, not zero only
through that interpolation across depth edges, is the floor a matcher is compared with. A frame without
correspondences (the first, or the first after a cut) has no flicker (NaN).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from ..errors import ShapeError
from .metrics import evaluate

__all__ = ["warp_previous", "flicker", "score_sequence", "summarise_frames", "comparison_rows", "FRAME_KEYS"]

#: What :func:`score_sequence` reports per frame, besides ``frame`` and ``scene``.
FRAME_KEYS = ("epe", "bad3", "seconds", "flicker", "flicker_gt")


def warp_previous(previous, previous_x) -> np.ndarray:
    """The previous frame's disparity read at ``previous_x`` along each row (linear interpolation); NaN where
    ``previous_x`` is NaN.

    Shapes
    ------
    previous, previous_x: (H, W) -> (H, W) float64.
    """
    prev = np.asarray(previous, dtype=np.float64)
    xs = np.asarray(previous_x, dtype=np.float64)
    if prev.ndim != 2 or prev.shape != xs.shape:
        raise ShapeError(f"warp_previous: needs two (H, W) maps of one shape, got previous={list(prev.shape)} "
                         f"previous_x={list(xs.shape)}")
    width = prev.shape[1]
    known = np.isfinite(xs)
    # x0 = floor(X) clamped to [0, W - 2], a = X - x0: d(X) = (1 - a) d[x0] + a d[x0 + 1]
    position = np.clip(np.where(known, xs, 0.0), 0.0, width - 1)
    x0 = np.minimum(np.floor(position).astype(np.int64), max(width - 2, 0))
    x1 = np.minimum(x0 + 1, width - 1)
    a = position - x0
    warped = (1 - a) * np.take_along_axis(prev, x0, axis=1) + a * np.take_along_axis(prev, x1, axis=1)
    return np.where(known, warped, np.nan)


def flicker(current, previous, previous_x) -> float:
    """``F_t``: the mean of ``|d_t - warp(d_{t-1})|`` over the pixels with a correspondence (finite ``previous_x``)
    where both disparities are finite; NaN when there is none.

    Shapes
    ------
    current, previous, previous_x: (H, W).
    """
    cur = np.asarray(current, dtype=np.float64)
    warped = warp_previous(previous, previous_x)
    if cur.shape != warped.shape:
        raise ShapeError(f"flicker: current disparity {list(cur.shape)} and previous {list(warped.shape)} differ")
    change = np.abs(cur - warped)
    known = np.isfinite(change)
    return float(change[known].mean()) if known.any() else math.nan


def score_sequence(frames: Sequence[dict], predict: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> list[dict]:
    """Runs ``predict(left, right)`` on the frames in order (a stream may carry state between calls) and scores
    every frame: ``epe`` and ``bad3`` over its valid pixels (:func:`mipnet.stereo.metrics.evaluate`), ``seconds``
    (the wall time of the call), ``flicker`` of the predictions and ``flicker_gt`` of the ground truth.

    ``frames`` are dicts with ``left``, ``right``, ``disparity``, ``valid``, ``previous_x`` (and optionally
    ``scene``), as :func:`mipnet.data.make_sequence` makes them.

    Returns
    -------
    list of dict
        One dict a frame: ``frame`` (its index), ``scene`` and :data:`FRAME_KEYS`.
    """
    records = []
    previous_pred = previous_gt = None
    for index, frame in enumerate(frames):
        start = time.perf_counter()
        disp = np.asarray(predict(frame["left"], frame["right"]), dtype=np.float32)
        seconds = time.perf_counter() - start
        metrics = evaluate(disp, frame["disparity"], frame["valid"])
        has_previous = previous_pred is not None and bool(np.isfinite(frame["previous_x"]).any())
        records.append({
            "frame": index, "scene": int(frame.get("scene", 0)), "epe": metrics["epe"], "bad3": metrics["bad3"],
            "seconds": seconds,
            "flicker": flicker(disp, previous_pred, frame["previous_x"]) if has_previous else math.nan,
            "flicker_gt": flicker(frame["disparity"], previous_gt, frame["previous_x"]) if has_previous else math.nan,
        })
        previous_pred, previous_gt = disp, frame["disparity"]
    return records


def _mean(values: Iterable[float]) -> float:
    finite = [v for v in values if not math.isnan(v)]
    return float(np.mean(finite)) if finite else math.nan


def summarise_frames(sequences: Sequence[Sequence[dict]]) -> dict:
    """Means over sequences of :func:`score_sequence`'s records: per frame index (``"frames"``, a list) and over
    every frame of every sequence (``"all"``); flicker means skip frames without one.

    Returns
    -------
    dict
        ``{"frames": [{"frame": t, **means}], "all": {**means, "frames": count}}``, means of :data:`FRAME_KEYS`.
    """
    count = max((len(records) for records in sequences), default=0)
    per_frame = []
    for t in range(count):
        at_t = [records[t] for records in sequences if len(records) > t]
        per_frame.append({"frame": t, **{key: _mean(r[key] for r in at_t) for key in FRAME_KEYS}})
    every = [r for records in sequences for r in records]
    return {"frames": per_frame, "all": {**{key: _mean(r[key] for r in every) for key in FRAME_KEYS},
                                         "frames": len(every)}}


def comparison_rows(summaries: dict[str, dict], keys: Sequence[str] = ("epe", "bad3", "seconds", "flicker")
                    ) -> tuple[list[dict], list[str]]:
    """Rows and columns of a table comparing methods frame by frame: a row per frame index and one ``all``, a
    column ``KEY METHOD`` per key and method (``summaries``: method -> :func:`summarise_frames`), then the ground
    truth's flicker. For :func:`mipnet.stereo.evaluation.format_table`.
    """
    columns = ["frame"] + [f"{key} {method}" for key in keys for method in summaries] + ["flicker gt"]
    first = next(iter(summaries.values()))
    rows = []
    for index, label in enumerate([row["frame"] for row in first["frames"]] + ["all"]):
        row = {"frame": label}
        for method, summary in summaries.items():
            values = summary["all"] if label == "all" else summary["frames"][index]
            row.update({f"{key} {method}": values[key] for key in keys})
        row["flicker gt"] = (first["all"] if label == "all" else first["frames"][index])["flicker_gt"]
        rows.append(row)
    return rows, columns
