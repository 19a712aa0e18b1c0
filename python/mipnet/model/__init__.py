"""The MIPNet model: the network and its building blocks, the loss, the memory estimate and the shipped weights.

* :mod:`~mipnet.model.config` — :class:`MIPNetConfig`, the ablation switches and input-size rules;
* :mod:`~mipnet.model.network` — :class:`MIPNet` and :func:`load`;
* :mod:`~mipnet.model.blocks` — encoder, attention fusion, correlation encoders, GRUs, heads;
* :mod:`~mipnet.model.losses` — the sequence loss and its metrics;
* :mod:`~mipnet.model.memory` — the peak-memory estimate checked before every pass;
* :mod:`~mipnet.model.pretrained` — where the shipped weights are and what their metadata says.

docs/architecture.md describes the network layer by layer.
"""

from . import blocks, config, losses, memory, network, pretrained
from .config import MIPNetConfig
from .network import MIPNet, gamma_draw, load

__all__ = ["MIPNet", "MIPNetConfig", "load", "gamma_draw", "blocks", "config", "losses", "memory", "network",
           "pretrained"]
