"""Learning-rate schedules (``torch.optim.lr_scheduler``)."""

from __future__ import annotations

from ..errors import ArgumentError
from . import Optimizer  # defined before mipnet.optim imports this module

__all__ = ["OneCycleLR"]


def __dir__() -> list[str]:
    """The API only (``dir(mipnet.optim.lr_scheduler)``, tab completion)."""
    return sorted(__all__)


class OneCycleLR:
    """The one-cycle schedule with linear annealing and no momentum cycling, as torch's
    ``OneCycleLR(max_lr, total_steps, pct_start, anneal_strategy='linear', cycle_momentum=False)``."""

    def __init__(self, optimizer: Optimizer, max_lr: float, total_steps: int, pct_start: float = 0.3,
                 anneal_strategy: str = "linear", div_factor: float = 25.0, final_div_factor: float = 1e4,
                 cycle_momentum: bool = False):
        if anneal_strategy != "linear" or cycle_momentum:
            raise ArgumentError("OneCycleLR: only anneal_strategy='linear' with cycle_momentum=False is supported")
        if total_steps < 2:
            raise ArgumentError(f"OneCycleLR: total_steps must be >= 2, got {total_steps}")
        self.optimizer, self.total_steps = optimizer, total_steps
        self.initial_lr = max_lr / div_factor
        self.max_lr, self.min_lr = max_lr, self.initial_lr / final_div_factor
        self.phases = [(pct_start * total_steps - 1, self.initial_lr, max_lr), (total_steps - 1, max_lr, self.min_lr)]
        self.last_step = 0
        self._set(self.lr_at(0))

    def lr_at(self, step: int) -> float:
        start = 0.0
        for i, (end, lr0, lr1) in enumerate(self.phases):
            if step <= end or i == len(self.phases) - 1:
                # linear interpolation over the phase: lr0 + (lr1 - lr0) * (step - start) / (end - start)
                return lr0 + (lr1 - lr0) * (step - start) / (end - start)
            start = end
        raise AssertionError("unreachable")

    def _set(self, lr: float) -> None:
        for g in self.optimizer.param_groups:
            g["lr"] = lr

    def step(self) -> None:
        self.last_step += 1
        if self.last_step >= self.total_steps:
            raise ArgumentError(f"OneCycleLR: stepped {self.last_step} times, beyond total_steps={self.total_steps}")
        self._set(self.lr_at(self.last_step))

    def get_last_lr(self) -> list[float]:
        return [g["lr"] for g in self.optimizer.param_groups]

    def state_dict(self) -> dict:
        """The schedule's position and shape (``torch.optim.lr_scheduler`` habit)."""
        return {"last_step": self.last_step, "total_steps": self.total_steps, "phases": [list(p) for p in self.phases],
                "initial_lr": self.initial_lr, "max_lr": self.max_lr, "min_lr": self.min_lr}

    def load_state_dict(self, sd: dict) -> None:
        self.total_steps, self.last_step = int(sd["total_steps"]), int(sd["last_step"])
        self.phases = [tuple(p) for p in sd["phases"]]
        self.initial_lr, self.max_lr, self.min_lr = sd["initial_lr"], sd["max_lr"], sd["min_lr"]
        self._set(self.lr_at(self.last_step))
