"""mipnet: MIPNet stereo matching on a CPU-first Rust engine, checked against PyTorch.

Quick start::

    import mipnet
    model = mipnet.MIPNet().eval()
    disparity = model(left_rgb_uint8, right_rgb_uint8)      # (H, W) float32, positive
"""

import os as _os

from . import _core
from . import errors
from .autograd import enable_grad, is_grad_enabled, no_grad
from .tensor import Tensor, tensor
from . import ops
from . import nn, optim, losses
from . import confidence, data, geometry, io, metrics, pretrained, training, underwater, utils, viz
from .confidence import match_confidence
from .model import MIPNet, MIPNetConfig, load
from .random import manual_seed

__version__ = _core.__version__


def set_num_threads(n: int) -> None:
    """Sets the number of threads of mipnet's kernels (also: environment variable ``MIPNET_NUM_THREADS``)."""
    _core.set_num_threads(int(n))


def get_num_threads() -> int:
    """The number of threads mipnet's kernels use."""
    return _core.get_num_threads()


# A forked child has none of the parent's pool threads: rebuild the pool there on first use.
_os.register_at_fork(after_in_child=_core._reset_after_fork)

__all__ = ["MIPNet", "MIPNetConfig", "load", "manual_seed", "nn", "optim", "losses", "confidence", "match_confidence", "data", "geometry", "io", "metrics", "pretrained", "training", "underwater", "utils", "viz", "Tensor", "tensor", "no_grad", "enable_grad", "is_grad_enabled", "ops", "errors",
           "set_num_threads", "get_num_threads", "__version__"]
