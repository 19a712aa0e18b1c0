"""mipnet beyond one machine, on Ray (``pip install 'mipnet[ray]'``; docs/distributed.md).

* :func:`infer_dataset` (``mipnet infer --ray``): pairs stream through Ray Data to actors holding one model
  each; outputs bitwise those of ``mipnet infer --batch-size 1``, resumable, failures in ``failures.jsonl``.
* :func:`fit` (``mipnet train --ray``): data-parallel training, the global batch split over Ray actors.

Ray is imported only when one of them runs: without it mipnet imports and works, and they raise a one-line
:class:`mipnet.errors.ArgumentError` naming the extra to install.
"""

from .cluster import RAY_INSTALL, connected, require_ray
from .infer import FAILURES_FILE, InferReport, PipelineError, infer_dataset
from .train import RayGradients, fit

__all__ = ["infer_dataset", "fit", "InferReport", "PipelineError", "RayGradients", "FAILURES_FILE", "RAY_INSTALL",
           "connected", "require_ray"]
