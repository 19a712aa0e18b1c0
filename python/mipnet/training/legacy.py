"""Training MIPNet (spec c.2): AdamW, one-cycle learning rate, gradient clipping at norm 1.0, the
sequence loss over all predictions, random crops, atomic checkpoints.

    from mipnet.data.synthetic import SyntheticStereo
    history = mipnet.training.train(model, SyntheticStereo(1000, 256, 320), TrainConfig(steps=200))
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from typing import Callable

import numpy as np

from ..data.loader import DataLoader
from ..errors import ArgumentError
from ..losses import sequence_loss, sequence_metrics
from ..model import MIPNet
from ..optim import AdamW, OneCycleLR, clip_grad_norm_


@dataclasses.dataclass
class TrainConfig:
    """Hyper-parameters; defaults are the paper's first pre-training stage except the step count."""

    steps: int = 1000
    batch_size: int = 8
    lr: float = 6e-4
    weight_decay: float = 1e-5
    pct_start: float = 0.01
    clip: float = 1.0
    iters: tuple[int, int] = (6, 6)
    gamma: float = 0.8
    max_disp: float = 700.0
    crop: tuple[int, int] | None = (384, 512)
    freeze_bn: bool = False
    seed: int = 1234
    num_workers: int = 0
    log_every: int = 10
    checkpoint: str | None = None
    checkpoint_every: int = 1000


def random_crop(size: tuple[int, int] | None) -> Callable:
    """A DataLoader transform cropping left, right, disparity and valid at one random position."""

    def transform(sample: dict, rng: np.random.Generator) -> dict:
        if size is None:
            return sample
        h, w = sample["left"].shape[:2]
        ch, cw = size
        if h < ch or w < cw:
            raise ArgumentError(f"random_crop: image {h}x{w} is smaller than the crop {ch}x{cw}")
        y, x = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
        return {k: (v[y:y + ch, x:x + cw] if isinstance(v, np.ndarray) and v.ndim >= 2 else v) for k, v in sample.items()}

    return transform


def train(model: MIPNet, dataset, config: TrainConfig, log: Callable[[dict], None] | None = None) -> list[dict]:
    """Runs ``config.steps`` optimisation steps and returns one metrics dict per step
    (loss, lr, grad norm, EPE and 1/3/5 px rates of the final prediction, seconds)."""
    loader = DataLoader(dataset, batch_size=config.batch_size, shuffle=True, drop_last=True,
                        num_workers=config.num_workers, seed=config.seed, transform=random_crop(config.crop))
    if len(loader) == 0:
        raise ArgumentError(f"train: dataset of {len(dataset)} samples gives no full batch of {config.batch_size}")
    optimizer = AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay, eps=1e-8)
    # total_steps = steps + 100 as RAFT-Stereo, so the schedule never runs out
    schedule = OneCycleLR(optimizer, config.lr, config.steps + 100, pct_start=config.pct_start)
    model.train()
    if config.freeze_bn:
        model.freeze_bn()
    history: list[dict] = []
    log = log or _print_log(config.log_every)
    step = 0
    while step < config.steps:
        for batch in loader:
            t0 = time.perf_counter()
            left, right = (batch[k].transpose(0, 3, 1, 2).astype(model.dtype) for k in ("left", "right"))
            preds = model(left, right, iters=config.iters)
            loss = sequence_loss(preds, batch["disparity"], batch["valid"], gamma=config.gamma, max_disp=config.max_disp)
            optimizer.zero_grad()
            loss.backward()
            grad_norm = clip_grad_norm_(model.parameters(), config.clip)
            optimizer.step()
            schedule.step()
            step += 1
            record = {"step": step, "loss": loss.item(), "lr": optimizer.param_groups[0]["lr"], "grad_norm": grad_norm,
                      **sequence_metrics(preds[-1], batch["disparity"], batch["valid"], config.max_disp),
                      "seconds": time.perf_counter() - t0}
            if not math.isfinite(record["loss"]):
                raise FloatingPointError(f"train: loss became {record['loss']} at step {step}")
            history.append(record)
            log(record)
            if config.checkpoint and (step % config.checkpoint_every == 0 or step == config.steps):
                model.save(config.checkpoint, step=str(step))
            if step >= config.steps:
                break
    return history


def _print_log(every: int) -> Callable[[dict], None]:
    def log(r: dict) -> None:
        if r["step"] == 1 or r["step"] % every == 0:
            print(f"step {r['step']:>6}  loss {r['loss']:.4f}  epe {r['epe']:.3f}  3px {100 * r['3px']:.1f}%  "
                  f"lr {r['lr']:.2e}  |g| {r['grad_norm']:.2f}  {r['seconds']:.1f}s", file=sys.stderr)

    return log
