"""The ``mipnet`` command line: ``infer``, ``eval``, ``train``, ``info``, ``fetch`` (one module each)."""

from .app import main

__all__ = ["main"]
