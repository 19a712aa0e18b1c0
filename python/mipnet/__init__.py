"""mipnet: MIPNet stereo matching on a CPU-first Rust engine, checked against PyTorch.

Quick start::

    import mipnet
    model = mipnet.MIPNet.pretrained()
    disparity = model(left_rgb_uint8, right_rgb_uint8)      # (H, W) float32, positive

The package has two layers (docs/architecture.md §5; enforced by import-linter, see pyproject.toml):

* the engine, as torch has it: :class:`Tensor`, :mod:`~mipnet.autograd`, :mod:`~mipnet.ops`,
  :mod:`~mipnet.nn`, :mod:`~mipnet.optim`, :mod:`~mipnet.random`, :mod:`~mipnet.profiler`,
  :mod:`~mipnet.serialization`, :mod:`~mipnet.utils` and the compiled kernels ``mipnet._core``;
* the application, one concern a folder: :mod:`~mipnet.model`, :mod:`~mipnet.stereo`,
  :mod:`~mipnet.underwater`, :mod:`~mipnet.data`, :mod:`~mipnet.training`, :mod:`~mipnet.inference`,
  :mod:`~mipnet.distributed` (on Ray), :mod:`~mipnet.cli`,
  :mod:`~mipnet.bench`.
"""

import importlib as _importlib
import os as _os
import warnings as _warnings

from . import _core
from . import errors
from .autograd import enable_grad, is_grad_enabled, no_grad
from .tensor import Tensor, tensor
from .random import manual_seed
from .amp import autocast
from . import amp, autograd, ops, nn, optim, profiler, random, serialization, utils
from . import model, stereo, underwater, data, training
from . import inference, distributed  # mipnet.distributed imports Ray only when it runs (the [ray] extra)
from .model import MIPNet, MIPNetConfig, Stream, load
from .stereo import match_confidence
from .stereo.rectify import rectify
from .export import export_onnx

__version__ = _core.__version__


def set_num_threads(n: int) -> None:
    """Sets the number of threads of mipnet's kernels (also: environment variable ``MIPNET_NUM_THREADS``)."""
    _core.set_num_threads(int(n))


def get_num_threads() -> int:
    """The number of threads mipnet's kernels use."""
    return _core.get_num_threads()


# A forked child has none of the parent's pool threads: rebuild the pool there on first use.
_os.register_at_fork(after_in_child=_core._reset_after_fork)

#: Module names of mipnet 0.1 that moved in 0.2 -> where they are now. Attribute access (``mipnet.metrics``)
#: still works with a DeprecationWarning until 0.3; ``import mipnet.metrics`` does not.
_MOVED = {
    "losses": "mipnet.model.losses", "memory": "mipnet.model.memory", "pretrained": "mipnet.model.pretrained",
    "blocks": "mipnet.model.blocks", "io": "mipnet.stereo.io", "metrics": "mipnet.stereo.metrics",
    "evaluation": "mipnet.stereo.evaluation", "geometry": "mipnet.stereo.geometry",
    "confidence": "mipnet.stereo.confidence", "baselines": "mipnet.stereo.baselines",
    "filters": "mipnet.stereo.filters", "viz": "mipnet.stereo.viz", "weights": "mipnet.serialization",
    "machine": "mipnet.bench.machine",
}


def __getattr__(name: str):
    if name in _MOVED:
        _warnings.warn(f"mipnet.{name} moved to {_MOVED[name]} in mipnet 0.2; the old name goes in 0.3",
                       DeprecationWarning, stacklevel=2)
        return _importlib.import_module(_MOVED[name])
    raise AttributeError(f"module 'mipnet' has no attribute {name!r}")


__all__ = ["MIPNet", "MIPNetConfig", "Stream", "load", "match_confidence", "Tensor", "tensor", "no_grad", "enable_grad",
           "is_grad_enabled", "autocast", "manual_seed", "set_num_threads", "get_num_threads", "__version__", "rectify", "export_onnx",
           "amp", "autograd", "ops", "nn", "optim", "profiler", "random", "serialization", "utils", "errors",
           "model", "stereo", "underwater", "data", "training", "inference", "distributed"]
