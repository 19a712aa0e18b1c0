"""``torch.utils.data`` names: ``Dataset``, ``ConcatDataset``, ``DataLoader``, ``default_collate``
(the same objects as ``mipnet.data``)."""

from ..data.datasets import ConcatDataset, Dataset
from ..data.loader import DataLoader, default_collate

__all__ = ["Dataset", "ConcatDataset", "DataLoader", "default_collate"]
