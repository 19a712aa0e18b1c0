"""Stereo vision around the network: file formats, metrics, evaluation, geometry, confidence, a classical
baseline, filters and colour maps. Nothing here needs the model; the model's users need all of it.

* :mod:`~mipnet.stereo.io` — PFM, KITTI/CREStereo 16-bit disparity PNGs, images, calibration files, NPY, PLY;
* :mod:`~mipnet.stereo.metrics` — EPE, bad-x, D1, quantiles and their aggregation;
* :mod:`~mipnet.stereo.evaluation` — evaluation loops and result tables (``mipnet eval``);
* :mod:`~mipnet.stereo.geometry` — disparity -> depth -> points;
* :mod:`~mipnet.stereo.rectify` — raw pairs from a calibrated rig: OpenCV stereo calibrations, rectification, depth;
* :mod:`~mipnet.stereo.confidence` — :func:`match_confidence`, where both views back a disparity;
* :mod:`~mipnet.stereo.baselines` — OpenCV's SGBM as a reference;
* :mod:`~mipnet.stereo.filters` — Gaussian and box filters;
* :mod:`~mipnet.stereo.viz` — colour maps for disparity pictures;
* :mod:`~mipnet.stereo.video` — stereo video in and disparity video out (PyAV), one colour range a sequence;
* :mod:`~mipnet.stereo.temporal` — per-frame scores and flicker of a disparity video.
"""

from . import baselines, confidence, evaluation, filters, geometry, io, metrics, rectify, temporal, video, viz
from .confidence import match_confidence

__all__ = ["io", "metrics", "evaluation", "geometry", "rectify", "confidence", "baselines", "filters", "viz",
           "video", "temporal", "match_confidence"]
