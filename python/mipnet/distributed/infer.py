"""Batch inference on Ray Data: ``mipnet infer --ray`` and :func:`infer_dataset` (docs/distributed.md).

The pairs stream through ``Dataset.map_batches`` to a pool of actors, each holding one model; every actor
reads its pairs, runs them one at a time and writes their outputs with the single-process command's code
(:func:`mipnet.inference.infer_pair`), so the outputs are bitwise those of ``mipnet infer --batch-size 1`` and
of ``model(left, right)``. The driver only lists the pairs, skips those already done, and collects what
the actors report: progress, and each failed pair in ``OUT/failures.jsonl``.

Inputs and the output folder must be on a file system every node sees (one machine, NFS, a mounted
bucket). The model travels through Ray's object store, so the weights file need exist only on the driver.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import queue
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from ..amp import autocast
from ..errors import MipnetError
from ..inference.failures import USER_ERRORS, naming
from ..inference.outputs import OutputOptions, OutputWriter, infer_pair
from ..inference.pairs import pair_reader, resolve_pairs
from ..utils.files import atomic_write
from .cluster import (ACTOR_CPUS, actors_per_node, check_workers, connected, default_workers, node_cpus,
                      require_ray, use_node_share)

FAILURES_FILE = "failures.jsonl"
#: seconds without a finished pair after which the run stops (a lost node, actors that cannot be placed)
STALL_TIMEOUT = 3600.0


class PipelineError(MipnetError):
    """The Ray pipeline stopped (an actor lost for good, no progress within the stall timeout); the outputs
    written so far are whole, and the same call resumes from them."""


@dataclasses.dataclass
class InferReport:
    """What a run did. ``run``: names of the pairs the actors ran through the model and wrote;
    ``skipped``: names whose outputs were complete before the run (no work at all); ``failed``: one record
    per failed pair (``left``, ``right``, ``name``, ``reason``, as in ``failures.jsonl``, plus ``traceback``);
    per pair that reached an actor, in the order they finished: the actor's ``threads`` and its ``seconds``
    for the pair (read, network, write), and when it finished (``finished``, seconds since the pipeline
    started: the first one includes the actors' start)."""

    total: int
    run: list[str] = dataclasses.field(default_factory=list)
    skipped: list[str] = dataclasses.field(default_factory=list)
    failed: list[dict] = dataclasses.field(default_factory=list)
    threads: list[int] = dataclasses.field(default_factory=list)
    seconds: list[float] = dataclasses.field(default_factory=list)
    finished: list[float] = dataclasses.field(default_factory=list)


class PairActor:
    """A Ray Data actor: one model, and the writer of ``mipnet infer``; a batch of rows in, one result row per
    pair out (``name``, ``ok``, ``reason``, ``traceback``, ``seconds``, ``threads``). ``weights`` holds one
    object reference to (config JSON, state dict), put once by the driver and shared by every actor."""

    def __init__(self, weights: list, out: str, options: OutputOptions, calib, read: Callable,
                 iters: tuple[int, int], seed: int, scale: float, cpus_by_node: dict[str, int], per_node: int,
                 precision: str = "fp32"):
        import ray

        from ..model.network import MIPNet

        self.threads = use_node_share(cpus_by_node, per_node)
        model_config, state = ray.get(weights[0])  # (config JSON, state dict) from the object store
        self.model = MIPNet(**json.loads(model_config))
        self.model.load_state_dict(state)
        self.model.eval()
        self.write = OutputWriter(options, Path(out), calib)
        self.read, self.iters, self.seed, self.scale = read, iters, seed, scale
        self.bf16 = precision == "bf16"

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, list]:
        rows: dict[str, list] = {key: [] for key in ("name", "ok", "reason", "traceback", "seconds", "threads")}
        for left, right, name in zip(batch["left"], batch["right"], batch["name"]):
            left, right, name = str(left), str(right), str(name)
            start = time.perf_counter()
            reason = trace = ""
            try:
                with autocast(enabled=self.bf16):
                    infer_pair(self.model, left, right, name, self.write, self.iters, self.seed, self.scale, read=self.read)
            except USER_ERRORS as error:
                reason, trace = naming((left, right), error), traceback.format_exc()
            for key, value in (("name", name), ("ok", not reason), ("reason", reason), ("traceback", trace),
                               ("seconds", time.perf_counter() - start), ("threads", self.threads)):
                rows[key].append(value)
        return rows


def _load_model(weights):
    """The model a run uses: a MIPNet as given, a weights file, or (None) the shipped weights."""
    import mipnet

    if weights is None:
        return mipnet.MIPNet.pretrained()
    if isinstance(weights, (str, os.PathLike)):
        return mipnet.load(os.fspath(weights)).eval()
    return weights


def _open_calibration(calib):
    """A calibration as given, or read from its file (:func:`mipnet.stereo.rectify.open_calibration`)."""
    from ..stereo.rectify import open_calibration

    return open_calibration(calib) if isinstance(calib, (str, os.PathLike)) else calib


def _write_failures(out: Path, failed: list[dict]) -> None:
    """``OUT/failures.jsonl``: one JSON object a failed pair (left, right, name, reason); none: no file."""
    path = out / FAILURES_FILE
    if not failed:
        path.unlink(missing_ok=True)
        return
    with atomic_write(path, "w") as f:
        for record in failed:
            f.write(json.dumps({k: record[k] for k in ("left", "right", "name", "reason")}) + "\n")


def _results(dataset, stall_timeout: float):
    """The rows of ``dataset`` as they finish; PipelineError if none arrives within ``stall_timeout`` s."""
    done = object()
    rows: queue.Queue = queue.Queue()

    def pump() -> None:
        try:
            for row in dataset.iter_rows():
                rows.put(row)
            rows.put(done)
        except BaseException as error:  # handed to the driver's thread, which raises it
            rows.put(error)

    threading.Thread(target=pump, name="mipnet-ray-results", daemon=True).start()
    while True:
        try:
            row = rows.get(timeout=stall_timeout)
        except queue.Empty:
            raise PipelineError(f"the Ray pipeline finished no pair in {stall_timeout:.0f} s (actors that "
                                "cannot be placed, or a lost node); the outputs so far are kept: run the same "
                                "command again to go on") from None
        if row is done:
            return
        if isinstance(row, BaseException):
            raise PipelineError(f"the Ray pipeline failed ({type(row).__name__}: "
                                f"{' '.join(str(row).split())[:500]}); the outputs so far are kept: run the same "
                                "command again to go on") from row
        yield row


@contextlib.contextmanager
def _quiet_ray_data(ray) -> Iterator[None]:
    """Ray Data without its progress bars and INFO lines while the block runs (the run has its own bar)."""
    context = ray.data.DataContext.get_current()
    logger = logging.getLogger("ray.data")
    bars, level = context.enable_progress_bars, logger.level
    context.enable_progress_bars = False
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        context.enable_progress_bars = bars
        logger.setLevel(level)


def infer_dataset(left_glob: str | None, right_glob: str | None, out_dir: str | os.PathLike, address: str | None = None,
                  workers: int | None = None, iters: Sequence[int] = (6, 6), weights=None, *, seed: int = 20,
                  scale: float = 1.0, calib=None, options: OutputOptions | None = None, read: Callable | None = None,
                  progress: bool = True, stall_timeout: float = STALL_TIMEOUT, precision: str = "fp32") -> InferReport:
    """Disparity maps for every pair the globs name, on a Ray cluster; resumable.

    Parameters
    ----------
    left_glob, right_glob : str or None
        As ``mipnet infer -l/-r``: a file, glob or folder(s) (:func:`mipnet.inference.resolve_pairs`).
    out_dir : path
        Where ``NAME_disp.npy`` / ``.pfm`` / ``.png`` (and the optional outputs) go, as ``mipnet infer -o``.
    address : str, optional
        The Ray cluster (:func:`mipnet.distributed.cluster.connected`); a session this process already has
        is used as it is.
    workers : int, optional
        Actors, each with one model (default: one per node); each runs on its node's cores / actors there.
    iters, seed, scale
        As ``model(left, right, iters=..., seed=..., scale=...)``.
    precision : str, default "fp32"
        "bf16": every actor runs the network under ``mipnet.autocast(dtype="bfloat16")`` (``mipnet infer
        --precision``).
    weights : str, MIPNet or None
        A weights file (on the driver), a model, or None for the shipped weights.
    calib : str, dict or Rectifier, optional
        A calibration file as ``mipnet infer --calib`` takes it, or what
        :func:`mipnet.stereo.rectify.open_calibration` returned: also depth and points; a rig calibration
        rectifies the raw pairs first.
    options : OutputOptions, optional
        The confidence and display options of ``mipnet infer``.
    read : callable, optional
        ``read(left_path, right_path) -> (left, right)`` (default :func:`mipnet.inference.pairs.pair_reader` of
        the calibration: rectified with a rig, as read otherwise).
    progress : bool
        A tqdm bar on stderr (pairs, pairs/s, ETA).
    stall_timeout : float
        Seconds without a finished pair after which the run stops with :class:`PipelineError`.

    Returns
    -------
    InferReport
        The pairs run, skipped (outputs already complete) and failed; the failures are also in
        ``OUT/failures.jsonl`` (absent when none failed).

    A pair counts as done when every file it would write exists: each is written atomically, so a file that
    exists is whole. A rerun with the same options skips those pairs without sending them to any actor.
    """
    from tqdm.auto import tqdm

    require_ray()
    check_workers(workers)
    pairs = resolve_pairs(left_glob, right_glob)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    options = options or OutputOptions()
    calib = _open_calibration(calib)
    read = read or pair_reader(calib)
    writer = OutputWriter(options, out, calib)
    report = InferReport(total=len(pairs))
    todo = []
    for left, right, name in pairs:
        if writer.complete(name):
            report.skipped.append(name)
        else:
            todo.append((left, right, name))
    if not todo:
        _write_failures(out, [])
        return report
    model = _load_model(weights)
    by_name = {name: (left, right) for left, right, name in todo}
    with connected(address) as ray, _quiet_ray_data(ray):
        cpus = node_cpus(ray)
        workers = min(workers or default_workers(ray), len(todo))
        # one pair a block, so that the pairs spread over the actors as they free up
        dataset = ray.data.from_items([{"left": left, "right": right, "name": name} for left, right, name in todo],
                                      override_num_blocks=len(todo))
        # Ray Data places an actor pool with its default strategy, SPREAD: the actors spread evenly over the nodes
        results = dataset.map_batches(
            PairActor, batch_size=1, compute=ray.data.ActorPoolStrategy(size=workers), num_cpus=ACTOR_CPUS,
            fn_constructor_kwargs=dict(weights=[ray.put((model.config.to_json(), model.state_dict()))], out=str(out),
                                       options=options, calib=calib, read=read, iters=tuple(iters), seed=seed,
                                       scale=scale, cpus_by_node=cpus, per_node=actors_per_node(workers, len(cpus)),
                                       precision=precision))
        bar = tqdm(total=len(todo), desc="infer", unit="pair", disable=not progress, file=sys.stderr,
                   dynamic_ncols=True, mininterval=0.5 if sys.stderr.isatty() else 30.0)
        start = time.perf_counter()
        with bar:
            for row in _results(results, stall_timeout):
                name = str(row["name"])
                report.threads.append(int(row["threads"]))
                report.seconds.append(float(row["seconds"]))
                report.finished.append(time.perf_counter() - start)
                if row["ok"]:
                    report.run.append(name)
                else:
                    left, right = by_name[name]
                    report.failed.append({"left": left, "right": right, "name": name, "reason": str(row["reason"]),
                                          "traceback": str(row["traceback"])})
                    _write_failures(out, report.failed)
                bar.set_postfix_str(name, refresh=False)
                bar.update(1)
    order = {name: index for index, (_, _, name) in enumerate(pairs)}
    report.failed.sort(key=lambda record: order[record["name"]])
    _write_failures(out, report.failed)
    return report
