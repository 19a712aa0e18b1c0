"""``plot(RUN)``: the training loss and the validation EPE of a run as a PNG (needs matplotlib)."""

from __future__ import annotations

import os

from ..utils.files import atomic_write
from .log import TrainLog


def _smooth(values: list[float], window: int) -> list[float]:
    """Running mean over the last ``window`` values (the first ones over what there is)."""
    out, total = [], 0.0
    for i, v in enumerate(values):
        total += v
        if i >= window:
            total -= values[i - window]
        out.append(total / min(i + 1, window))
    return out


def plot(run_dir: str, path: str | None = None, window: int = 25) -> str:
    """Draws loss and training EPE per step (raw and a running mean) and the validation EPE of each
    set (SGBM's as dashed lines) to ``path`` (default ``RUN/curves.png``); returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = TrainLog(os.path.join(run_dir, "log.jsonl")).records()
    steps = [r for r in records if "loss" in r and r.get("loss") is not None]
    vals = [r for r in records if "val" in r]
    sgbm = next((r["val_sgbm"] for r in records if "val_sgbm" in r), None)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for ax, key in zip(axes[:2], ("loss", "epe")):
        x = [r["step"] for r in steps]
        y = [r[key] for r in steps]
        ax.plot(x, y, color="0.8", lw=0.8, label="per step")
        ax.plot(x, _smooth(y, window), color="C0", label=f"mean of {window}")
        ax.set(xlabel="step", ylabel=f"training {key}", yscale="log")
        ax.legend()
    ax = axes[2]
    names = sorted({k for r in vals for k in r["val"]})
    for i, name in enumerate(names):
        pts = [(r["step"], r["val"][name]["epe"]) for r in vals if name in r["val"]]
        ax.plot(*zip(*pts), marker="o", color=f"C{i}", label=name)
        if sgbm and name in sgbm:
            ax.axhline(sgbm[name]["epe"], color=f"C{i}", ls="--", lw=0.8)
    ax.set(xlabel="step", ylabel="validation EPE (px; dashed: SGBM)", yscale="log")
    if names:
        ax.legend()
    fig.suptitle(os.path.basename(os.path.abspath(run_dir)))
    fig.tight_layout()
    path = path or os.path.join(run_dir, "curves.png")
    with atomic_write(path) as f:
        fig.savefig(f, format="png", dpi=100)
    plt.close(fig)
    return path
