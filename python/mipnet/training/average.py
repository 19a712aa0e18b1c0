"""An exponential moving average of a model's parameters over the steps of a run (Polyak averaging).

Fine-tuning on a mixture of sources moves the weights back and forth between what suits one source
and another; the validation of single steps' weights swung by 20-50% between checkpoints 200 steps
apart (docs/training.md). The average over the last ~1 / (1 - decay) steps follows the trend and not
the last batches. With ``TrainConfig.ema_decay`` set, ``fit`` updates it after every optimiser step,
keeps it in the checkpoint (so a resumed run continues it exactly), validates it and writes it as the
run's weights. BatchNorm's running statistics are themselves running averages and are taken from
the model as they are.
"""

from __future__ import annotations

import contextlib
from typing import Iterator, Mapping

import numpy as np

from ..errors import ArgumentError


class WeightAverage:
    """avg ← decay · avg + (1 − decay) · θ for every parameter θ of ``model``, started at the model's
    current parameters (a fine-tuning run's initial weights)."""

    def __init__(self, model, decay: float):
        if not 0.0 < decay < 1.0:
            raise ArgumentError(f"WeightAverage: decay must lie in (0, 1), got {decay}")
        self.decay = float(decay)
        self._params = dict(model.named_parameters())
        self.values = {name: np.array(p.data, copy=True) for name, p in self._params.items()}

    def update(self) -> None:
        """One step of the average, after an optimiser step."""
        keep = np.float32(self.decay)
        for name, p in self._params.items():
            avg = self.values[name]
            # avg = decay · avg + (1 − decay) · θ, written as avg += (1 − decay) · (θ − avg)
            avg += (1 - keep) * (p.data.astype(avg.dtype, copy=False) - avg)

    def state_dict(self) -> dict[str, np.ndarray]:
        return dict(self.values)

    def load_state_dict(self, values: Mapping[str, np.ndarray]) -> None:
        missing, unknown = set(self.values) - set(values), set(values) - set(self.values)
        if missing or unknown:
            raise ArgumentError(f"WeightAverage.load_state_dict: parameters missing {sorted(missing)[:3]}, "
                                f"unknown {sorted(unknown)[:3]}")
        for name, value in values.items():
            if value.shape != self.values[name].shape:
                raise ArgumentError(f"WeightAverage.load_state_dict: {name} has shape {value.shape}, "
                                    f"the model's {self.values[name].shape}")
            self.values[name] = np.array(value, dtype=self.values[name].dtype, copy=True)

    @contextlib.contextmanager
    def applied(self) -> Iterator[None]:
        """Within the block the model's parameters hold the average; the step's own values come back
        after it, bitwise."""
        saved = {name: p.data.copy() for name, p in self._params.items()}
        try:
            for name, p in self._params.items():
                p.data[...] = self.values[name]
            yield
        finally:
            for name, p in self._params.items():
                p.data[...] = saved[name]
