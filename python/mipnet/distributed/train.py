"""Data-parallel training on Ray actors: ``mipnet train --ray`` and :func:`fit` (docs/distributed.md).

The driver runs :func:`mipnet.training.fit` as one process does (the data loader, the gradient clipping, the
AdamW step, the schedule, validation, checkpoints and exact resume, SIGINT/SIGTERM) except for the forward
and backward pass of each step, which :class:`RayGradients` spreads over N actors:

1. the driver draws the step's initial disparities from mipnet's global generator, as the one-process forward
   would (architecture.md §2.4), so the generator, and the checkpoints, advance exactly as in one process;
2. it splits the global batch into N contiguous shares and puts the weights into Ray's object store once;
3. actor k loads the weights and back-propagates ``C_k / C`` times the sequence loss of its share (``C_k`` valid
   pixels of ``C`` in the batch): the one-process loss is the mean over all ``C``, so the weighted sum of the
   shares' losses is the batch's loss, and the sum of their gradients its gradient;
4. the driver sums the N gradient sets in worker order (a fixed reduction order) and steps.

The driver steps and sends the weights each step (rather than every actor stepping its own copy): one
optimiser, one writer of checkpoints. In training mode BatchNorm normalises each share with its own statistics
(as torch's DDP does by default, no SyncBatchNorm) and the running statistics of worker 0 are kept (DDP's
``broadcast_buffers``); with ``--freeze-bn`` they are fixed and N workers give the one-process run's losses
and weights up to float rounding (tests_py/test_distributed.py states the tolerance).

A worker that is lost (or fails, or does not answer within the step timeout) stops the run with
:class:`mipnet.training.fit.StepFailed` after a checkpoint at the step it was in: ``--resume`` continues exactly.
"""

from __future__ import annotations

import json
import time

import numpy as np

from ..errors import ArgumentError
from ..model.config import DIVISOR
from ..model.losses import valid_mask
from ..model.network import MIPNet, gamma_draw
from ..random import default_generator
from ..tensor import Tensor
from ..training.config import TrainConfig
from ..training.fit import StepFailed, backward_pass
from ..training.fit import fit as fit_one_process
from .cluster import ACTOR_CPUS, actors_per_node, check_workers, connected, default_workers, node_cpus, use_node_share

#: seconds a step (or the actors' start) may take before the run stops as if a worker had been lost
STEP_TIMEOUT = 3600.0


def initial_disparities(model: MIPNet, n: int, h: int, w: int) -> np.ndarray:
    """The initial disparities the training forward of ``model`` draws for n pairs of h x w from mipnet's global
    generator (architecture.md §2.4), (n, 1, H16, W16) in 1/16-level pixels: its ``disp_init``."""
    config = model.config
    # the 1/16 grid of the input padded to a multiple of 16: H16 = ceil(h / 16), W16 = ceil(w / 16)
    h16, w16 = -(-h // DIVISOR), -(-w // DIVISOR)
    return gamma_draw(default_generator(), (n, 1, h16, w16), config.gamma_shape, config.gamma_scale,
                      config.max_disp_init) / 16.0


class GradientWorker:
    """A Ray actor: a MIPNet in training mode that computes the gradients of its share of each step."""

    def __init__(self, model_config: str, freeze_bn: bool, cpus_by_node: dict[str, int], per_node: int):
        self.threads = use_node_share(cpus_by_node, per_node)
        self.model = MIPNet(**json.loads(model_config)).train()
        if freeze_bn:
            self.model.freeze_bn()

    def ready(self) -> int:
        """The kernel threads this actor runs (answering also says it was placed and started)."""
        return self.threads

    def gradients(self, state: dict, share: dict, disp_init: np.ndarray, weight: float, config: TrainConfig,
                  with_buffers: bool) -> dict:
        """``weight`` times the loss of ``share`` back-propagated from the weights ``state``: the loss, the final
        prediction (n, 1, H, W), each parameter's gradient in ``parameters()`` order (None where it got none),
        the BatchNorm buffers after the pass if asked, and the seconds of the forward and backward pass."""
        self.model.load_state_dict(state)
        self.model.zero_grad()
        start = time.perf_counter()
        loss, final = backward_pass(self.model, share, config, disp_init=disp_init, weight=weight)
        grads = [None if p.grad is None else p.grad.data for p in self.model.parameters()]
        buffers = dict(self.model.named_buffers()) if with_buffers else None
        return {"loss": loss, "final": final, "grads": grads, "buffers": buffers,
                "seconds": time.perf_counter() - start}


def _sum_in_order(arrays: list) -> np.ndarray | None:
    """((a_0 + a_1) + a_2) + ...: the workers' gradients of one parameter in worker order; None if none has one."""
    present = [a for a in arrays if a is not None]
    if not present:
        return None
    total = np.array(present[0], copy=True)
    for a in present[1:]:
        total += a
    return total


class RayGradients:
    """``gradients(model, batch, config)`` for :func:`mipnet.training.fit.fit` over ``workers`` Ray actors
    (module docstring). ``timings`` holds, per step, the seconds spent putting the weights into the object
    store (``broadcast``), waiting for the actors (``wait``), the slowest actor's forward and backward pass
    (``compute``) and summing the gradients (``reduce``): the exchange of weights and gradients (the
    all-reduce) costs ``broadcast + wait - compute + reduce``."""

    def __init__(self, ray, workers: int, timeout: float = STEP_TIMEOUT):
        self.ray, self.workers, self.timeout = ray, workers, timeout
        self.actors: list = []
        self.threads: list[int] = []
        self.timings: list[dict] = []

    def _start(self, model: MIPNet, config: TrainConfig) -> None:
        ray = self.ray
        cpus = node_cpus(ray)
        per_node = actors_per_node(self.workers, len(cpus))
        actor = ray.remote(GradientWorker).options(num_cpus=ACTOR_CPUS, scheduling_strategy="SPREAD", max_restarts=0)
        self.actors = [actor.remote(model.config.to_json(), config.freeze_bn, cpus, per_node)
                       for _ in range(self.workers)]
        self.threads = self._gather([a.ready.remote() for a in self.actors], "start")

    def _gather(self, futures: list, what: str) -> list:
        """Each future's value in worker order, within the timeout; StepFailed naming the worker otherwise."""
        ray = self.ray
        deadline = time.monotonic() + self.timeout
        values = []
        for k, future in enumerate(futures):
            try:
                values.append(ray.get(future, timeout=max(0.0, deadline - time.monotonic())))
            except ray.exceptions.GetTimeoutError:
                raise StepFailed(f"Ray worker {k + 1} of {len(futures)} did not {what} within {self.timeout:.0f} s")
            except ray.exceptions.RayError as error:
                cause = " ".join(str(error).split())[:300]
                raise StepFailed(f"Ray worker {k + 1} of {len(futures)} was lost ({type(error).__name__}: {cause})") \
                    from error
        return values

    def __call__(self, model: MIPNet, sample: dict, config: TrainConfig) -> tuple[float, np.ndarray]:
        n, h, w = sample["left"].shape[:3]
        if n < self.workers:
            raise ArgumentError(f"mipnet train --ray: a batch of {n} pairs cannot be split over {self.workers} "
                                "workers: give --batch-size of at least the number of workers")
        if not self.actors:
            self._start(model, config)
        generator = default_generator()
        before = generator.bit_generator.state
        try:
            return self._step(model, sample, config, initial_disparities(model, n, h, w))
        except StepFailed:
            generator.bit_generator.state = before  # the step did not happen: its draws neither
            raise

    def _step(self, model: MIPNet, sample: dict, config: TrainConfig, disp_init: np.ndarray) -> tuple[float, np.ndarray]:
        ray = self.ray
        shares = np.array_split(np.arange(len(sample["left"])), self.workers)
        valid = valid_mask(sample["disparity"], sample["valid"], config.max_disp)
        counts = [int(valid[rows].sum()) for rows in shares]
        total = sum(counts)
        start = time.perf_counter()
        state = ray.put(model.state_dict())
        sent = time.perf_counter()
        futures = [actor.gradients.remote(state, {key: value[rows] for key, value in sample.items()}, disp_init[rows],
                                          counts[k] / total if total else 0.0, config,
                                          k == 0 and not config.freeze_bn)
                   for k, (actor, rows) in enumerate(zip(self.actors, shares))]
        results = self._gather(futures, "finish its share of the step")
        received = time.perf_counter()
        for index, p in enumerate(model.parameters()):
            total_grad = _sum_in_order([r["grads"][index] for r in results])
            p.grad = None if total_grad is None else Tensor(total_grad)
        if results[0]["buffers"] is not None:  # BatchNorm in training mode: worker 0's running statistics
            model.load_state_dict(results[0]["buffers"], strict=False)
        self.timings.append({"broadcast": sent - start, "wait": received - sent,
                             "compute": max(r["seconds"] for r in results), "reduce": time.perf_counter() - received})
        loss = 0.0
        for r in results:
            loss += r["loss"]
        return loss, np.concatenate([r["final"] for r in results])

    def close(self) -> None:
        """Ends the actors."""
        for actor in self.actors:
            self.ray.kill(actor)
        self.actors = []


def fit(config: TrainConfig | None, out: str, *, resume: bool = False, steps: int | None = None,
        progress: bool = True, overrides: dict | None = None, address: str | None = None,
        workers: int | None = None, timeout: float = STEP_TIMEOUT) -> list[dict]:
    """:func:`mipnet.training.fit.fit` with each step's gradients computed by ``workers`` Ray actors.

    Parameters
    ----------
    config, out, resume, steps, progress, overrides
        As :func:`mipnet.training.fit.fit`; ``config.batch_size`` is the global batch, split over the workers.
    address : str, optional
        The Ray cluster (:func:`mipnet.distributed.cluster.connected`).
    workers : int, optional
        Actors (default: one per node), each running on its node's cores / actors there.
    timeout : float
        Seconds a step may take before the run stops as if a worker had been lost.

    A run started here resumes with or without Ray, and the other way round: only the reduction order of the
    gradients differs (module docstring).
    """
    check_workers(workers)
    with connected(address) as ray:
        gradients = RayGradients(ray, workers or default_workers(ray), timeout)
        try:
            return fit_one_process(config, out, resume=resume, steps=steps, progress=progress, overrides=overrides,
                                   gradients=gradients)
        finally:
            gradients.close()
