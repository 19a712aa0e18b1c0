"""Resumable training state in ``RUN/checkpoint/``: one safetensors file per checkpoint.

A checkpoint holds the model's state dict (parameters and BatchNorm buffers), AdamW's moments and
step counts, the one-cycle schedule's position, the training step, the data loader's position
(epoch and batch) and the state of mipnet's global generator (the gamma draws of training mode),
the run's ``TrainConfig`` and, when the run keeps one, the moving average of the weights. Its metadata carries a SHA-256 digest of every tensor and every other
metadata entry (the step, the loader's position, the config...), so a file that was damaged after it was
written is detected on load (files of the first format, whose digest covered the tensors only, still load); writes are atomic, so a file is never
half-written. The newest :data:`KEEP` checkpoints are kept; loading falls back to the previous one
when the newest is unreadable.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import re
from typing import Mapping

import numpy as np

from ..errors import FormatError
from ..serialization import load_safetensors, save_safetensors

KEEP = 2
FORMAT = "mipnet-checkpoint-2"
#: The first format: the same file with a digest of the tensors only.
TENSOR_DIGEST_FORMAT = "mipnet-checkpoint-1"
_NAME = re.compile(r"^ckpt-(\d{8})\.safetensors$")

logger = logging.getLogger(__name__)


@dataclasses.dataclass
class TrainState:
    """Everything that continues a run exactly."""

    step: int
    epoch: int
    batch: int
    model: dict[str, np.ndarray]
    optimizer: dict
    schedule: dict
    rng_state: dict
    config_json: str
    model_config: str
    #: The parameters' moving average (``TrainConfig.ema_decay``), or None.
    average: dict[str, np.ndarray] | None = None


def _digest(tensors: Mapping[str, np.ndarray], meta: Mapping[str, str] | None = None) -> str:
    """SHA-256 over (name, dtype, shape, bytes) of every tensor in name order, then (with ``meta``) every
    metadata entry but the digest itself in key order."""
    h = hashlib.sha256()
    for name in sorted(tensors):
        a = np.ascontiguousarray(tensors[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    for key in sorted(meta or {}):
        if key != "digest":
            h.update(json.dumps([key, meta[key]]).encode())
    return h.hexdigest()


def _flatten(state: TrainState) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    tensors = {f"model/{k}": v for k, v in state.model.items()}
    for index, entries in state.optimizer["state"].items():
        for name, value in entries.items():
            tensors[f"optim/{index}/{name}"] = np.asarray(value)
    tensors.update({f"average/{k}": v for k, v in (state.average or {}).items()})
    meta = {"format": FORMAT, "step": str(state.step), "epoch": str(state.epoch), "batch": str(state.batch),
            "schedule": json.dumps(state.schedule), "rng_state": json.dumps(state.rng_state),
            "param_groups": json.dumps(state.optimizer["param_groups"]), "config": state.config_json,
            "model_config": state.model_config}
    meta["digest"] = _digest(tensors, meta)
    return tensors, meta


def _unflatten(tensors: dict[str, np.ndarray], meta: dict[str, str], path: str) -> TrainState:
    if meta.get("format") not in (FORMAT, TENSOR_DIGEST_FORMAT):
        raise FormatError(f"{path}: not a mipnet training checkpoint (format {meta.get('format')!r})")
    if meta.get("digest") != _digest(tensors, meta if meta["format"] == FORMAT else None):
        raise FormatError(f"{path}: checkpoint digest mismatch (the file was damaged after it was written)")
    model = {k[len("model/"):]: v for k, v in tensors.items() if k.startswith("model/")}
    average = {k[len("average/"):]: v for k, v in tensors.items() if k.startswith("average/")} or None
    optim_state: dict[int, dict] = {}
    for key, value in tensors.items():
        if key.startswith("optim/"):
            _, index, name = key.split("/", 2)
            optim_state.setdefault(int(index), {})[name] = value
    try:
        return TrainState(step=int(meta["step"]), epoch=int(meta["epoch"]), batch=int(meta["batch"]), model=model,
                          optimizer={"state": optim_state, "param_groups": json.loads(meta["param_groups"])},
                          schedule=json.loads(meta["schedule"]), rng_state=json.loads(meta["rng_state"]),
                          config_json=meta["config"], model_config=meta["model_config"], average=average)
    except (KeyError, ValueError) as e:
        raise FormatError(f"{path}: checkpoint metadata is incomplete ({e})") from None


def checkpoint_dir(run_dir: str) -> str:
    return os.path.join(run_dir, "checkpoint")


def list_checkpoints(run_dir: str) -> list[str]:
    """Checkpoint files of a run, newest first."""
    folder = checkpoint_dir(run_dir)
    if not os.path.isdir(folder):
        return []
    names = sorted((n for n in os.listdir(folder) if _NAME.match(n)), reverse=True)
    return [os.path.join(folder, n) for n in names]


def save_checkpoint(run_dir: str, state: TrainState) -> str:
    """Writes ``checkpoint/ckpt-STEP.safetensors`` atomically and removes all but the newest KEEP."""
    folder = checkpoint_dir(run_dir)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, f"ckpt-{state.step:08d}.safetensors")
    tensors, meta = _flatten(state)
    save_safetensors(path, tensors, meta)
    for old in list_checkpoints(run_dir)[KEEP:]:
        os.remove(old)
    return path


def read_checkpoint(path: str) -> TrainState:
    """One checkpoint file; ``FormatError`` if it is not a complete, undamaged checkpoint."""
    try:
        tensors, meta = load_safetensors(path)
    except OSError as e:
        raise FormatError(f"{path}: cannot read checkpoint: {e.strerror}") from None
    return _unflatten(tensors, meta, path)


def load_latest_checkpoint(run_dir: str) -> TrainState:
    """The newest readable checkpoint of a run (an unreadable newer one is reported and skipped)."""
    paths = list_checkpoints(run_dir)
    if not paths:
        raise FormatError(f"{run_dir}: no checkpoint to resume from (expected {checkpoint_dir(run_dir)}/ckpt-*.safetensors)")
    errors = []
    for path in paths:
        try:
            state = read_checkpoint(path)
        except FormatError as e:
            errors.append(str(e))
            logger.warning("mipnet train: warning: skipping %s", e)
            continue
        return state
    raise FormatError(f"{run_dir}: every checkpoint is unreadable: " + "; ".join(errors))
