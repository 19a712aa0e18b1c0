"""The MIPNet model: the network and its building blocks, the loss, the memory estimate and the shipped weights.

* :mod:`~mipnet.model.config` — :class:`MIPNetConfig`, the ablation switches and input-size rules;
* :mod:`~mipnet.model.network` — :class:`MIPNet` and :func:`load`;
* :mod:`~mipnet.model.state` — :class:`NetworkState`, the fields and hidden states a pass ends in and can start from;
* :mod:`~mipnet.model.stream` — :class:`Stream`, video frames warm-started from the previous frame;
* :mod:`~mipnet.model.blocks` — encoder, attention fusion, correlation encoders, GRUs, heads;
* :mod:`~mipnet.model.losses` — the sequence loss and its metrics;
* :mod:`~mipnet.model.memory` — the peak-memory estimate checked before every pass;
* :mod:`~mipnet.model.pretrained` — where the shipped weights are and what their metadata says.

docs/architecture.md describes the network layer by layer.
"""

from . import blocks, config, losses, memory, network, pretrained, state, stream
from .config import MIPNetConfig
from .network import MIPNet, gamma_draw, load
from .state import NetworkState
from .stream import Stream

__all__ = ["MIPNet", "MIPNetConfig", "load", "gamma_draw", "NetworkState", "Stream", "blocks", "config", "losses",
           "memory", "network", "pretrained", "state", "stream"]
