"""Optimisers and schedules of MIPNet's recipe (spec c.2): AdamW, SGD, OneCycleLR, clip_grad_norm_.

Updates replace ``p.data`` between steps (never while a kernel reads it), with torch's formulas.
"""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

from .errors import ArgumentError
from .tensor import Tensor


class Optimizer:
    """Holds ``param_groups`` (list of dicts with ``params`` and hyper-parameters) and per-parameter state."""

    def __init__(self, params: Iterable[Any], defaults: dict):
        params = list(params)
        if not params:
            raise ArgumentError(f"{type(self).__name__}: got an empty parameter list")
        groups = params if isinstance(params[0], dict) else [{"params": params}]
        self.param_groups = [{**defaults, **g, "params": list(g["params"])} for g in groups]
        self.state: dict[int, dict] = {}

    def zero_grad(self, set_to_none: bool = True) -> None:
        for g in self.param_groups:
            for p in g["params"]:
                p.grad = None if set_to_none or p.grad is None else p.grad.zero_()

    def state_dict(self) -> dict:
        index = {id(p): i for i, p in enumerate(p for g in self.param_groups for p in g["params"])}
        return {"state": {index[k]: {n: np.array(v, copy=True) for n, v in s.items()} for k, s in self.state.items()},
                "param_groups": [{k: v for k, v in g.items() if k != "params"} for g in self.param_groups]}

    def load_state_dict(self, sd: dict) -> None:
        params = [p for g in self.param_groups for p in g["params"]]
        self.state = {id(params[int(i)]): {n: np.array(v, copy=True) for n, v in s.items()} for i, s in sd["state"].items()}
        for g, saved in zip(self.param_groups, sd["param_groups"]):
            g.update(saved)


class SGD(Optimizer):
    """p <- p - lr * (g + weight_decay * p), with optional momentum (``torch.optim.SGD``)."""

    def __init__(self, params, lr: float = 1e-3, momentum: float = 0.0, weight_decay: float = 0.0):
        super().__init__(params, dict(lr=lr, momentum=momentum, weight_decay=weight_decay))

    def step(self) -> None:
        for g in self.param_groups:
            for p in g["params"]:
                if p.grad is None:
                    continue
                d = p.grad.data + g["weight_decay"] * p.data
                if g["momentum"]:
                    buf = self.state.setdefault(id(p), {}).get("momentum_buffer")
                    buf = d.copy() if buf is None else g["momentum"] * buf + d
                    self.state[id(p)]["momentum_buffer"] = buf
                    d = buf
                p.data = (p.data - g["lr"] * d).astype(p.dtype)


class AdamW(Optimizer):
    """Adam with decoupled weight decay (``torch.optim.AdamW``; MIPNet: wd 1e-5, eps 1e-8)."""

    def __init__(self, params, lr: float = 1e-3, betas=(0.9, 0.999), eps: float = 1e-8, weight_decay: float = 1e-2):
        super().__init__(params, dict(lr=lr, betas=tuple(betas), eps=eps, weight_decay=weight_decay))

    def step(self) -> None:
        for g in self.param_groups:
            b1, b2 = g["betas"]
            for p in g["params"]:
                if p.grad is None:
                    continue
                st = self.state.setdefault(id(p), {"step": np.zeros((), np.int64),
                                                   "exp_avg": np.zeros_like(p.data), "exp_avg_sq": np.zeros_like(p.data)})
                st["step"] = st["step"] + 1
                t, grad = int(st["step"]), p.grad.data
                data = p.data * (1 - g["lr"] * g["weight_decay"])
                st["exp_avg"] = b1 * st["exp_avg"] + (1 - b1) * grad
                st["exp_avg_sq"] = b2 * st["exp_avg_sq"] + (1 - b2) * grad * grad
                # p -= lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)
                denom = np.sqrt(st["exp_avg_sq"]) / math.sqrt(1 - b2 ** t) + g["eps"]
                p.data = (data - (g["lr"] / (1 - b1 ** t)) * st["exp_avg"] / denom).astype(p.dtype)


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


def clip_grad_norm_(parameters: Iterable[Tensor], max_norm: float) -> float:
    """Scales all gradients so their joint L2 norm is at most ``max_norm``; returns the norm before."""
    grads = [p.grad for p in parameters if p.grad is not None]
    total = math.sqrt(sum(float(np.sum(g.data.astype(np.float64) ** 2)) for g in grads))
    coef = max_norm / (total + 1e-6)
    if coef < 1.0:
        for g in grads:
            g.data *= coef
    return total
