"""mipnet's exceptions. Every one derives from ``RuntimeError`` (as torch's shape errors do).

The kernel errors are created once in Rust (``src/python/errors.rs``) and re-exported here, so
``except mipnet.errors.ShapeError`` catches what the compiled core raises.
"""

from ._core import ArgumentError, DTypeError, InvalidValueError, MipnetError, ShapeError


class FormatError(MipnetError):
    """A file is corrupt, truncated, or not in the format its reader expects."""


__all__ = ["MipnetError", "ShapeError", "ArgumentError", "DTypeError", "InvalidValueError", "FormatError"]
