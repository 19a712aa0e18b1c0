"""``fit``: the training loop behind ``mipnet train`` (architecture.md §3.1–§3.3), with exact resume.

A run lives in one folder::

    RUN/log.jsonl             one JSON object per step and per validation
    RUN/model.safetensors     the latest weights (``mipnet.load``; their moving average with ``ema_decay``)
    RUN/best.safetensors      the weights of the best validation so far (mean EPE over the generated sets)
    RUN/config.json           the resolved TrainConfig
    RUN/checkpoint/           the resumable state (see :mod:`mipnet.training.checkpoint`)

``fit(config, RUN)`` starts a run; ``fit(None, RUN, resume=True, steps=N)`` continues it to step N
exactly as if it had never stopped: same data order, augmentation, gamma draws, optimiser state and
schedule, so the losses and weights are bitwise those of an uninterrupted run. SIGINT and SIGTERM end
the current step, write a checkpoint and return.

The forward and backward pass of a step is ``gradients(model, batch, config)`` (:func:`backward_pass` by
default); :func:`mipnet.distributed.fit` passes one that splits the batch over Ray actors. Everything else (the
data, the clipping, the AdamW step, the schedule, the checkpoints) stays on this process.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import os
import signal
import sys
import time
from typing import Callable, Iterator, Sequence

import numpy as np

from .._core import __version__
from ..utils.files import atomic_write
from ..utils.data.dataloader import DataLoader
from ..errors import ArgumentError, MipnetError
from ..model.losses import sequence_loss, sequence_metrics
from ..model.network import MIPNet, load
from ..optim import AdamW, OneCycleLR, clip_grad_norm_
from ..random import default_generator, manual_seed
from .augment import make_augmentor
from .average import WeightAverage
from .checkpoint import TrainState, list_checkpoints, load_latest_checkpoint, save_checkpoint
from .config import RESUMABLE_OVERRIDES, TrainConfig
from ..data.registry import EVAL_SEED_START, Mixture, is_sparse, open_spec, parse_spec, renders_sensor_noise
from .log import TrainLog
from .validation import format_validation, mean_epe, validate_model, validate_sgbm, validation_sets

# Generated training pairs are drawn this much larger than the crop, so scale augmentation can
# shrink them (2**-0.2 = 0.87) and crops land at varied positions.
GENERATED_MARGIN = 1.25

# Validation tables go out at INFO, a stop on a signal at WARNING; `mipnet train` shows both on stderr
# (mipnet.cli.train), from Python configure logging (e.g. logging.basicConfig(level=logging.INFO)).
logger = logging.getLogger(__name__)


def _generated_size(crop: tuple[int, int]) -> tuple[int, int]:
    """Size of generated training pairs for a crop: crop * margin, rounded up to a multiple of 8."""
    return tuple(int(math.ceil(c * GENERATED_MARGIN / 8) * 8) for c in crop)  # type: ignore[return-value]


def build_dataset(config: TrainConfig) -> tuple[Mixture, list]:
    """The training mixture of ``config.data`` and one augmentor per source (dense or sparse)."""
    specs = [parse_spec(text) for text in config.data]
    size = _generated_size(config.crop)
    sources = [open_spec(spec, size, seed=0, count=EVAL_SEED_START) for spec in specs]
    options = {"scale_range": config.spatial_scale}
    if config.augment and config.veil > 0:
        options["veil_prob"] = config.veil

    def noise_options(spec) -> dict:
        noisy = config.augment and config.noise > 0 and not (config.noise_sources == "air" and renders_sensor_noise(spec))
        return {"noise_prob": config.noise} if noisy else {}

    augmentors = [make_augmentor(config.crop, sparse=is_sparse(spec), augment=config.augment, **options, **noise_options(spec))
                  for spec in specs]
    return Mixture(sources, [s.weight for s in specs], EVAL_SEED_START, seed=config.seed), augmentors


def _transform(augmentors: list):
    def transform(sample: dict, rng: np.random.Generator) -> dict:
        out = augmentors[sample["source"]](sample, rng)
        return {k: out[k] for k in ("left", "right", "disparity", "valid")}

    return transform


class StepFailed(MipnetError):
    """A step that failed before it changed the run's state (a distributed worker was lost): the step loop
    writes a checkpoint at the current position, which resumes the run exactly, and re-raises."""


class StopRequest:
    """SIGINT/SIGTERM set a flag; the loop checkpoints after the current step and returns (shared by
    ``mipnet train`` and ``mipnet adapt``; ``command`` names the one that reports the signal)."""

    def __init__(self, command: str = "mipnet train") -> None:
        self.signal: int | None = None
        self.command = command

    @contextlib.contextmanager
    def installed(self) -> Iterator["StopRequest"]:
        if threading_is_main():
            previous = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
        else:
            previous = {}
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)

    def _handle(self, signum, frame) -> None:
        if self.signal is not None:  # a second signal: stop now
            raise KeyboardInterrupt
        self.signal = signum
        logger.warning("%s: %s received: checkpointing after this step", self.command, signal.Signals(signum).name)


def threading_is_main() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def save_json(path: str, obj) -> None:
    with atomic_write(path, "w") as f:
        json.dump(obj, f, indent=2, sort_keys=True)


def _weights_metadata(config: TrainConfig, step: int, **extra) -> dict:
    from ..data import scenes

    return {"step": str(step), "train_config": config.to_json(), "mipnet_version": __version__,
            "generator_version": str(getattr(scenes, "GENERATOR_VERSION", "")),
            **{k: v if isinstance(v, str) else json.dumps(v) for k, v in extra.items()}}


def _new_model(config: TrainConfig) -> MIPNet:
    manual_seed(config.seed)
    if config.init:
        if not os.path.isfile(config.init):
            raise ArgumentError(f"mipnet train: --init {config.init}: no such file")
        return load(config.init)
    return MIPNet()



def progress_bar(desc: str, total: int, initial: int, progress: bool):
    """The steps' progress bar on stderr (tqdm), refreshed every second on a terminal, every 30 s in a log."""
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="step", disable=not progress, file=sys.stderr,
                mininterval=1.0 if sys.stderr.isatty() else 30.0, dynamic_ncols=True)


def epochs_of(loader: DataLoader, epoch: int) -> Iterator[tuple[int, dict]]:
    """(epoch, batch) without end: the loader's batches, one epoch after the other, from where
    ``loader.set_epoch`` put it (an epoch's iterator ends where the next one begins)."""
    while True:
        for sample in loader:
            yield epoch, sample
        epoch += 1


@dataclasses.dataclass
class Position:
    """Where a run stands: its optimisation step, and the loader's epoch and batch within that epoch."""

    step: int = 0
    epoch: int = 0
    batch: int = 0


def run_steps(command: str, position: Position, target: int, loader: DataLoader, take_step: Callable[[dict], dict],
              *, log: TrainLog, progress: bool, periodic: Sequence[tuple[int, Callable[[], None]]],
              checkpoint: Callable[[], None], out: str, resume_command: str,
              postfix: Callable[[dict], dict]) -> list[dict]:
    """The step loop that ``fit`` and ``adapt`` share: until ``target`` or a stop signal, one ``take_step(batch)``
    per loader batch (its record gets the step and the seconds spent), the record logged, each ``(period, hook)``
    of ``periodic`` called every ``period`` steps, a checkpoint at the end; ``position`` follows along."""
    records: list[dict] = []
    stop = StopRequest(command)
    bar = progress_bar(command.split()[-1], target, position.step, progress)
    with stop.installed(), bar:
        batches = epochs_of(loader, position.epoch)
        while position.step < target and stop.signal is None:
            t_data = time.perf_counter()
            sample_epoch, sample = next(batches)
            if sample_epoch != position.epoch:  # the loader moved on to the next epoch, from its first batch
                position.epoch, position.batch = sample_epoch, 0
            t0 = time.perf_counter()
            try:
                body = take_step(sample)
            except StepFailed as error:
                checkpoint()
                raise StepFailed(f"{command}: step {position.step + 1} failed: {error}; the run is saved at step "
                                 f"{position.step}: continue with {resume_command}") from error
            position.step, position.batch = position.step + 1, position.batch + 1
            record = {"step": position.step, **body, "seconds": time.perf_counter() - t0, "data_seconds": t0 - t_data}
            if not math.isfinite(record["loss"]):
                raise FloatingPointError(f"{command}: loss became {record['loss']} at step {position.step}; "
                                         f"the last checkpoint in {out}/checkpoint is from before")
            log.append(record)
            records.append(record)
            bar.set_postfix(**postfix(record), refresh=False)
            bar.update(1)
            for period, hook in periodic:
                if position.step % period == 0:
                    hook()
    checkpoint()
    if stop.signal is not None:
        logger.warning("%s: stopped at step %d; continue with: %s", command, position.step, resume_command)
    return records


def backward_pass(model: MIPNet, sample: dict, config: TrainConfig, *, disp_init: np.ndarray | None = None,
                  weight: float = 1.0) -> tuple[float, np.ndarray]:
    """The forward and backward pass of one training batch on this process: ``weight`` times the sequence loss
    (architecture.md §3.1) is back-propagated into the parameters' ``.grad``.

    Parameters
    ----------
    model : MIPNet
        In training mode.
    sample : dict
        ``left``, ``right`` (N, H, W, 3) and ``disparity``, ``valid`` (N, H, W), as the training loader gives them.
    config : TrainConfig
        The run's ``iters``, ``gamma`` and ``max_disp``.
    disp_init : numpy.ndarray, optional
        (N, 1, H/16, W/16) initial disparities instead of the model's draw from the global generator.
    weight : float
        The share of this batch in a larger one whose loss is the mean over all its valid pixels.

    Returns
    -------
    loss : float
        ``weight`` times the batch's loss.
    final : numpy.ndarray
        The last prediction (N, 1, H, W), for the step's metrics.
    """
    left, right = (sample[k].transpose(0, 3, 1, 2).astype(model.dtype) for k in ("left", "right"))
    preds = model(left, right, iters=config.iters, disp_init=disp_init)
    loss = sequence_loss(preds, sample["disparity"], sample["valid"], gamma=config.gamma, max_disp=config.max_disp,
                         edge_weight=config.edge_weight)
    if weight != 1.0:
        loss = loss * weight
    loss.backward()
    return loss.item(), preds[-1].numpy()


def fit(config: TrainConfig | None, out: str, *, resume: bool = False, steps: int | None = None,
        progress: bool = True, overrides: dict | None = None,
        gradients: Callable[[MIPNet, dict, TrainConfig], tuple[float, np.ndarray]] = backward_pass) -> list[dict]:
    """Trains MIPNet and returns the step records of this call.

    Parameters
    ----------
    config : TrainConfig or None
        The run's settings (None with ``resume``: the checkpoint's).
    out : str
        The run folder.
    resume : bool
        Continue the run in ``out`` from its newest readable checkpoint.
    steps : int, optional
        Train until this step (default: ``config.steps``).
    progress : bool
        Show a tqdm progress bar on stderr.
    overrides : dict, optional
        With ``resume``: settings that may change between sessions without changing results
        (:data:`mipnet.training.config.RESUMABLE_OVERRIDES`).
    gradients : callable
        ``gradients(model, batch, config) -> (loss, final prediction)`` leaves the batch's gradients in the
        parameters' ``.grad`` (default :func:`backward_pass`, on this process). One that raises
        :class:`StepFailed` stops the run after a checkpoint at the current position.

    Each validation's table is logged at INFO on the ``mipnet.training.fit`` logger, a stop on SIGINT or
    SIGTERM at WARNING (``mipnet train`` shows both on stderr).
    """
    os.makedirs(out, exist_ok=True)
    state: TrainState | None = None
    if resume:
        state = load_latest_checkpoint(out)
        config = TrainConfig.from_json(state.config_json)
        bad = sorted(set(overrides or {}) - set(RESUMABLE_OVERRIDES))
        if bad:
            raise ArgumentError(f"mipnet train --resume: {bad} cannot change in a resumed run (only {list(RESUMABLE_OVERRIDES)})")
        config = dataclasses.replace(config, **{k: v for k, v in (overrides or {}).items() if v is not None})
    elif config is None:
        raise ArgumentError("fit: needs a TrainConfig unless resume=True")
    elif list_checkpoints(out):
        raise ArgumentError(f"mipnet train: {out} already holds a run; continue it with --resume {out} or choose another --out")
    target = int(steps if steps is not None else config.steps)
    if config.schedule_steps is None:  # the schedule spans the run's planned length, whatever a call stops at
        config = dataclasses.replace(config, schedule_steps=config.steps)
    if target + 1 > config.schedule_steps + 100:
        raise ArgumentError(f"mipnet train: the one-cycle schedule of this run ends at step {config.schedule_steps + 100}; "
                            f"start a new stage with --init {os.path.join(out, 'model.safetensors')} to train to {target}")

    model = _new_model(config) if state is None else MIPNet(**json.loads(state.model_config))
    optimizer = AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay, eps=1e-8)
    schedule = OneCycleLR(optimizer, config.lr, config.schedule_steps + 100, pct_start=config.pct_start)
    dataset, augmentors = build_dataset(config)
    loader = DataLoader(dataset, batch_size=config.batch_size, shuffle=True, drop_last=True,
                        num_workers=config.workers, seed=config.seed, transform=_transform(augmentors))
    log = TrainLog(os.path.join(out, "log.jsonl"))
    position = Position()
    if state is not None:
        model.load_state_dict(state.model)
        optimizer.load_state_dict(state.optimizer)
        schedule.load_state_dict(state.schedule)
        default_generator().bit_generator.state = state.rng_state
        position = Position(state.step, state.epoch, state.batch)
    average = WeightAverage(model, config.ema_decay) if config.ema_decay else None
    if average is not None and state is not None and state.average is not None:
        average.load_state_dict(state.average)
    # the weights a run validates and saves: the moving average where it keeps one
    saved_weights = average.applied if average is not None else contextlib.nullcontext
    log.truncate_after(position.step)
    save_json(os.path.join(out, "config.json"), dataclasses.asdict(config))
    loader.set_epoch(position.epoch, position.batch)

    model.train()
    if config.freeze_bn:
        model.freeze_bn()
    val_sets = validation_sets(config.val_size, config.val_pairs, config.val_data) if config.val_every and config.val_pairs else None
    previous = log.records()
    best = min((mean_epe(r["val"]) for r in previous if "val" in r), default=math.inf)
    sgbm_logged = any("val_sgbm" in r for r in previous)

    def checkpoint() -> None:
        save_checkpoint(out, TrainState(step=position.step, epoch=position.epoch, batch=position.batch,
                                        model=model.state_dict(), optimizer=optimizer.state_dict(),
                                        schedule=schedule.state_dict(), rng_state=default_generator().bit_generator.state,
                                        config_json=config.to_json(), model_config=model.config.to_json(),
                                        average=average.state_dict() if average is not None else None))
        with saved_weights():
            model.save(os.path.join(out, "model.safetensors"), **_weights_metadata(config, position.step))

    def validate() -> None:
        nonlocal best, sgbm_logged
        model.eval()
        with saved_weights():
            table = validate_model(lambda l, r: model(l, r, iters=config.val_iters), val_sets)
        model.train()
        reference = None
        if not sgbm_logged:
            reference = validate_sgbm(val_sets)
            if reference is not None:
                log.append({"step": position.step, "val_sgbm": reference})
            sgbm_logged = True
        log.append({"step": position.step, "val": table})
        logger.info("%s", format_validation(position.step, table, reference))
        score = mean_epe(table)
        if score < best:
            best = score
            with saved_weights():
                model.save(os.path.join(out, "best.safetensors"), **_weights_metadata(config, position.step, validation=table))

    def train_step(sample: dict) -> dict:
        optimizer.zero_grad()
        loss, final = gradients(model, sample, config)
        grad_norm = clip_grad_norm_(model.parameters(), config.clip)
        lr = optimizer.param_groups[0]["lr"]
        optimizer.step()
        if average is not None:
            average.update()
        schedule.step()
        return {"loss": loss, "lr": lr, "grad_norm": grad_norm,
                **sequence_metrics(final, sample["disparity"], sample["valid"], config.max_disp)}

    periodic = [(config.checkpoint_every, checkpoint)] + ([(config.val_every, validate)] if val_sets is not None else [])
    return run_steps("mipnet train", position, target, loader, train_step, log=log, progress=progress,
                     periodic=periodic, checkpoint=checkpoint, out=out, resume_command=f"mipnet train --resume {out}",
                     postfix=lambda r: {"loss": f"{r['loss']:.3f}", "epe": f"{r['epe']:.2f}"})

