"""The ``mipnet`` command line: ``infer``, ``eval``, ``train``, ``info``, ``fetch``."""

from .app import main

__all__ = ["main"]
