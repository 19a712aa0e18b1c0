"""Optimisers of MIPNet's recipe (architecture.md §3.2), at torch's import paths: ``mipnet.optim.AdamW``, ``SGD``,
``mipnet.optim.lr_scheduler.OneCycleLR`` (also here), and ``clip_grad_norm_`` (``mipnet.nn.utils``; also here).

Updates replace ``p.data`` between steps (never while a kernel reads it), with torch's formulas.
"""

from __future__ import annotations

import math
from typing import Any, Iterable

import numpy as np

from ..errors import ArgumentError

__all__ = ["Optimizer", "SGD", "AdamW", "OneCycleLR", "lr_scheduler", "clip_grad_norm_"]


def __dir__() -> list[str]:
    """The API only (``dir(mipnet.optim)``, tab completion): not the modules this one imports."""
    return sorted(__all__)


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


from . import lr_scheduler  # noqa: E402 - the schedule module needs Optimizer defined
from .lr_scheduler import OneCycleLR  # noqa: E402
from ..nn.utils import clip_grad_norm_  # noqa: E402
