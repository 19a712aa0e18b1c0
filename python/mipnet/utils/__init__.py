"""Engine utilities: datasets and loading (:mod:`mipnet.utils.data`, as ``torch.utils.data``), the
allocator's settings (:mod:`mipnet.utils.allocator`) and atomic file writes (:mod:`mipnet.utils.files`)."""

from . import allocator, data, files

__all__ = ["allocator", "data", "files"]
