"""A small, seeded, PyTorch-like DataLoader over numpy samples, with optional worker processes.

Determinism: the shuffle order of epoch ``e`` comes from ``(seed, e)``, and the ``transform`` of
the sample at position ``p`` of that order gets its own generator seeded from ``(seed, e, p)``.
The batches are therefore identical with any ``num_workers``. Workers also seed Python's
``random`` and numpy's global state from ``(seed, e, worker_id)`` for code that uses them.
"""

from __future__ import annotations

import collections
import itertools
import multiprocessing
import random
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from numbers import Number

import numpy as np

from ...errors import ShapeError

__all__ = ["DataLoader", "default_collate"]


def default_collate(samples: Sequence[dict]) -> dict:
    """Stack a list of sample dicts into a batch dict.

    Arrays are stacked into a new leading axis, numbers become 1-D arrays, everything else
    (strings, ``meta`` dicts, None) is kept as a list.

    Shapes
    ------
    each array value: (...) -> (B, ...).

    Raises
    ------
    ShapeError
        Arrays under one key differ in shape (crop or resize in ``transform``, or use
        ``batch_size=1``).
    """
    batch = {}
    for key in samples[0]:
        values = [sample[key] for sample in samples]
        if isinstance(values[0], np.ndarray):
            shapes = {v.shape for v in values}
            if len(shapes) > 1:
                raise ShapeError(
                    f"cannot batch {key!r}: shapes {sorted(shapes)} differ; crop in transform or use batch_size=1"
                )
            batch[key] = np.stack(values)
        elif isinstance(values[0], Number) and not isinstance(values[0], bool):
            batch[key] = np.asarray(values)
        else:
            batch[key] = values
    return batch


def _seed_state(*entropy: int) -> int:
    return int(np.random.SeedSequence(list(entropy)).generate_state(1)[0])


# Worker-process state, set by the pool initializer (inherited by fork, pickled by spawn).
_WORKER: dict = {}


def _init_worker(loader: DataLoader, epoch: int, counter) -> None:
    # The parent owns Ctrl-C and SIGTERM (a training run checkpoints on them); a worker ends when told.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    with counter.get_lock():
        worker_id = counter.value
        counter.value += 1
    seed = _seed_state(loader.seed, epoch, worker_id)
    random.seed(seed)
    np.random.seed(seed % 2**32)
    _WORKER.update(loader=loader, epoch=epoch, worker_id=worker_id)


def _load_batch_in_worker(positions_and_indices):
    return _WORKER["loader"]._load_batch(_WORKER["epoch"], positions_and_indices)


class DataLoader:
    """Iterate a map-style dataset in (optionally shuffled) batches of stacked numpy arrays.

    Parameters
    ----------
    dataset : Dataset
        Anything with ``__len__`` and ``__getitem__`` returning dicts.
    batch_size : int
        Samples per batch.
    shuffle : bool
        Reshuffle every epoch (the epoch counter advances with each ``iter()``; see
        :meth:`set_epoch`).
    drop_last : bool
        Drop the last incomplete batch.
    num_workers : int
        0: load in this process; >0: that many worker processes ("fork" start method on Linux).
    seed : int
        Seed of shuffling and of the per-sample transform generators.
    collate_fn : callable, optional
        ``list of samples -> batch``; default :func:`default_collate`.
    transform : callable, optional
        ``transform(sample, rng) -> sample``, applied per sample with a
        ``numpy.random.Generator`` that depends only on (seed, epoch, position).

    Shapes
    ------
    batch arrays: (B, ...) with B = batch_size (smaller for a last partial batch).
    """

    def __init__(self, dataset, batch_size: int = 1, shuffle: bool = False, drop_last: bool = False,
                 num_workers: int = 0, seed: int = 0, collate_fn: Callable | None = None,
                 transform: Callable | None = None):
        if batch_size < 1:
            raise ValueError(f"DataLoader: batch_size must be >= 1, got {batch_size}")
        if num_workers < 0:
            raise ValueError(f"DataLoader: num_workers must be >= 0, got {num_workers}")
        self.dataset = dataset
        self.batch_size = batch_size
        self.shuffle = shuffle
        self.drop_last = drop_last
        self.num_workers = num_workers
        self.seed = seed
        self.collate_fn = collate_fn or default_collate
        self.transform = transform
        self.epoch = 0
        self.start_batch = 0

    def __len__(self) -> int:
        full, rest = divmod(len(self.dataset), self.batch_size)
        return full + (1 if rest and not self.drop_last else 0)

    def set_epoch(self, epoch: int, start_batch: int = 0) -> None:
        """Set the epoch whose order the next ``iter()`` uses (it then advances by one), and the
        batch of that epoch to start from (resuming a run mid-epoch loads nothing it skips)."""
        if not 0 <= start_batch <= len(self):
            raise ValueError(f"DataLoader: start_batch must be in 0..{len(self)}, got {start_batch}")
        self.epoch = int(epoch)
        self.start_batch = int(start_batch)

    def _batches(self, epoch: int, start: int = 0) -> Iterator[list[tuple[int, int]]]:
        """(position, dataset index) pairs of every batch of ``epoch`` from batch ``start`` on."""
        count = len(self.dataset)
        if self.shuffle:
            order = np.random.default_rng(_seed_state(self.seed, epoch)).permutation(count)
        else:
            order = np.arange(count)
        size = self.batch_size
        for first in range(start * size, len(self) * size, size):
            # batch b holds positions b*size .. b*size + size - 1 (the last one may be shorter)
            yield list(enumerate(order[first:first + size].tolist(), start=first))

    def _load_batch(self, epoch: int, positions_and_indices: list[tuple[int, int]]):
        samples = []
        for position, index in positions_and_indices:
            sample = self.dataset[index]
            if self.transform is not None:
                rng = np.random.default_rng(_seed_state(self.seed, epoch, position))
                sample = self.transform(sample, rng)
            samples.append(sample)
        return self.collate_fn(samples)

    def __iter__(self) -> Iterator:
        epoch, start = self.epoch, self.start_batch
        self.epoch, self.start_batch = epoch + 1, 0
        batches = self._batches(epoch, start)
        if self.num_workers == 0:
            return (self._load_batch(epoch, batch) for batch in batches)
        return self._iter_workers(epoch, batches)

    def _iter_workers(self, epoch: int, batches: Iterator) -> Iterator:
        # concurrent.futures rather than multiprocessing.Pool: a worker killed by a signal (a
        # `kill` of the whole process group) breaks the executor instead of deadlocking shutdown
        # on the queue lock the dead worker held.
        method = "fork" if sys.platform.startswith("linux") else "spawn"
        context = multiprocessing.get_context(method)
        counter = context.Value("i", 0)
        pool = ProcessPoolExecutor(self.num_workers, mp_context=context, initializer=_init_worker,
                                   initargs=(self, epoch, counter))
        try:
            # Keep at most two batches per worker in flight; results come back in submission order.
            pending: collections.deque = collections.deque(
                pool.submit(_load_batch_in_worker, batch) for batch in itertools.islice(batches, 2 * self.num_workers))
            while pending:
                result = pending.popleft().result()
                following = next(batches, None)
                if following is not None:
                    pending.append(pool.submit(_load_batch_in_worker, following))
                yield result
        except BrokenProcessPool as exc:
            raise RuntimeError(f"DataLoader: a worker process died (killed by a signal or out of memory): {exc}") from exc
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
