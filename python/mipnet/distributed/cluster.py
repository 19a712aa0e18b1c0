"""Connecting to a Ray cluster, and sizing the actors that run mipnet on it (docs/distributed.md).

Ray is optional (``pip install 'mipnet[ray]'``): it is imported only here, inside functions, so that mipnet
imports and works without it, and :func:`require_ray` turns its absence into one line naming the extra.

Every actor reserves :data:`ACTOR_CPUS` of Ray's CPU resource, a scheduling token rather than its thread
count: Ray Data's own tasks then always find a CPU (actors of one whole CPU each starved them on a 2-core
machine, and the pipeline never finished). The threads of an actor are set explicitly instead
(:func:`actor_threads`): the node's cores shared by the actors placed on it.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from typing import Any

from ..errors import ArgumentError

#: what to install for ``--ray`` (the ``ray`` extra of pyproject.toml: ``ray[data]``)
RAY_INSTALL = "pip install 'mipnet[ray]'"
#: Ray's CPU resource each actor reserves: a token that leaves room for Ray Data's tasks, not its threads
ACTOR_CPUS = 0.5


def require_ray(needed_for: str = "--ray"):
    """The ``ray`` module; ArgumentError (one line, what to install) if it is not installed."""
    try:
        import ray
        import ray.data  # Ray Data (pandas, pyarrow): the [data] part of the extra
    except ImportError:
        raise ArgumentError(f"{needed_for} needs Ray (the ray module with Ray Data): {RAY_INSTALL}") from None
    return ray


@contextlib.contextmanager
def connected(address: str | None) -> Iterator[Any]:
    """A Ray session for the duration of the block: the one this process already has, or one joined here.

    ``address`` None: the cluster named by ``RAY_ADDRESS`` or started on this machine with ``ray start``,
    else a new local one (``ray.init()``'s rule); ``"auto"``: an existing cluster only; ``"host:6379"`` or
    ``"ray://host:10001"``: that cluster. A session joined here is left at the end of the block."""
    ray = require_ray()
    if ray.is_initialized():
        yield ray
        return
    ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="warning")
    try:
        yield ray
    finally:
        ray.shutdown()


def node_cpus(ray) -> dict[str, int]:
    """The CPU count Ray sees on each live node, by node id."""
    return {node["NodeID"]: int(node["Resources"].get("CPU", 0)) for node in ray.nodes() if node["Alive"]}


def default_workers(ray) -> int:
    """One actor per live node (each then runs on all of the node's cores)."""
    return max(1, len(node_cpus(ray)))


def actors_per_node(workers: int, nodes: int) -> int:
    """How many of ``workers`` actors the SPREAD strategy puts on the fullest of ``nodes`` nodes."""
    # actors spread evenly: ceil(workers / nodes) on the fullest node
    return max(1, math.ceil(workers / max(1, nodes)))


def actor_threads(cpus_by_node: dict[str, int], per_node: int, node_id: str) -> int:
    """Kernel threads of an actor on ``node_id``: the node's cores shared by the ``per_node`` actors on it."""
    return max(1, cpus_by_node.get(node_id, 1) // per_node)


def use_node_share(cpus_by_node: dict[str, int], per_node: int) -> int:
    """In an actor: sets mipnet's kernel threads to this node's share (:func:`actor_threads`); the count."""
    import ray

    import mipnet

    threads = actor_threads(cpus_by_node, per_node, ray.get_runtime_context().get_node_id())
    mipnet.set_num_threads(threads)
    return threads


def check_workers(workers: int | None) -> None:
    """ArgumentError unless ``workers`` is None (the default) or a positive count."""
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise ArgumentError(f"workers must be a positive number of Ray actors, got {workers!r}")
