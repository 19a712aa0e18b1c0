"""Datasets and loading, at torch's import path (``torch.utils.data``): ``Dataset``, ``ConcatDataset``,
``RepeatDataset``, ``DataLoader``, ``default_collate``. The stereo datasets built on them are in
:mod:`mipnet.data`."""

from .dataloader import DataLoader, default_collate
from .dataset import ConcatDataset, Dataset, RepeatDataset

__all__ = ["Dataset", "ConcatDataset", "RepeatDataset", "DataLoader", "default_collate"]
