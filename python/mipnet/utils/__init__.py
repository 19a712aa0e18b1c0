"""torch-style import paths: ``mipnet.utils.data.Dataset`` / ``DataLoader`` (``torch.utils.data``)."""

from . import data

__all__ = ["data"]
