"""mipnet's exceptions. Every one derives from ``RuntimeError`` (as torch's shape errors do).

The kernel errors are created once in Rust (``src/python/errors.rs``) and re-exported here, so
``except mipnet.errors.ShapeError`` catches what the compiled core raises.

Hierarchy::

    RuntimeError
     └─ MipnetError                 bad input of any kind
         ├─ ShapeError              ranks or sizes do not fit (an op, the model, a pair of images)
         ├─ ArgumentError           a scalar argument or option is invalid
         ├─ DTypeError              not float32 / float64, or mixed dtypes
         ├─ InvalidValueError       unusable values (NaN where it matters, ...)
         ├─ FormatError             a file is corrupt, truncated or not in its reader's format
         └─ MemoryLimitError        (also a MemoryError) a pass would need more memory than is available

Readers raise :class:`FormatError` for a bad file and the usual ``OSError`` subclasses
(``FileNotFoundError``, ``IsADirectoryError``, ``PermissionError``) for a file they cannot open.
"""

from ._core import ArgumentError, DTypeError, InvalidValueError, MipnetError, ShapeError


class FormatError(MipnetError):
    """A file is corrupt, truncated, or not in the format its reader expects."""


class MemoryLimitError(MipnetError, MemoryError):
    """A forward pass or training step would need more memory than the machine has available.

    Raised before the pass starts (see :mod:`mipnet.model.memory`); ``estimate`` and ``available`` are in
    bytes."""

    def __init__(self, message: str, estimate: int = 0, available: int = 0):
        super().__init__(message)
        self.estimate, self.available = estimate, available


__all__ = ["MipnetError", "ShapeError", "ArgumentError", "DTypeError", "InvalidValueError", "FormatError",
           "MemoryLimitError"]
