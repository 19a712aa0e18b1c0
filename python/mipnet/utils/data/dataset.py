"""Map-style datasets (``torch.utils.data.dataset``): the base class and its concatenation and repetition."""

from __future__ import annotations

import bisect
from collections.abc import Sequence

import numpy as np

__all__ = ["Dataset", "ConcatDataset", "RepeatDataset"]


class Dataset:
    """Base of map-style datasets: ``len(ds)``, ``ds[i]``, ``ds + other``, ``k * ds``."""

    def __len__(self) -> int:
        raise NotImplementedError

    def __getitem__(self, index: int) -> dict:
        raise NotImplementedError

    def __iter__(self):
        for index in range(len(self)):
            yield self[index]

    def __add__(self, other: Dataset) -> ConcatDataset:
        if not isinstance(other, Dataset):
            return NotImplemented
        return ConcatDataset([self, other])

    def __mul__(self, times: int) -> RepeatDataset:
        if not isinstance(times, int) or isinstance(times, bool):
            return NotImplemented
        return RepeatDataset(self, times)

    __rmul__ = __mul__

    def _check_index(self, index: int) -> int:
        index = int(index)
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"{type(self).__name__} index {index} out of range (length {len(self)})")
        return index


class ConcatDataset(Dataset):
    """The samples of several datasets, one after another (nested concatenations are flattened)."""

    def __init__(self, datasets: Sequence[Dataset]):
        self.datasets: list[Dataset] = []
        for dataset in datasets:
            self.datasets.extend(dataset.datasets if isinstance(dataset, ConcatDataset) else [dataset])
        self._ends = np.cumsum([len(d) for d in self.datasets]).tolist()

    def __len__(self) -> int:
        return self._ends[-1] if self._ends else 0

    def __getitem__(self, index: int) -> dict:
        index = self._check_index(index)
        which = bisect.bisect_right(self._ends, index)
        start = self._ends[which - 1] if which else 0
        return self.datasets[which][index - start]


class RepeatDataset(Dataset):
    """A dataset repeated ``times`` times (index i maps to ``dataset[i % len(dataset)]``)."""

    def __init__(self, dataset: Dataset, times: int):
        if times < 0:
            raise ValueError(f"RepeatDataset: times must be >= 0, got {times}")
        self.dataset = dataset
        self.times = times

    def __len__(self) -> int:
        return len(self.dataset) * self.times

    def __getitem__(self, index: int) -> dict:
        return self.dataset[self._check_index(index) % len(self.dataset)]
