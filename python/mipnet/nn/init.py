"""Weight initialisers on numpy arrays (``torch.nn.init``), drawing from mipnet's global generator."""

from __future__ import annotations

import math

import numpy as np

from ..random import default_generator
from ..tensor import Tensor


def _fans(shape: tuple[int, ...]) -> tuple[int, int]:
    # conv weight [out, in, kh, kw]: fan_in = in*kh*kw, fan_out = out*kh*kw
    receptive = int(np.prod(shape[2:])) if len(shape) > 2 else 1
    return shape[1] * receptive, shape[0] * receptive


def kaiming_normal_(t: Tensor, mode: str = "fan_in", nonlinearity: str = "relu") -> Tensor:
    """N(0, gain² / fan) with gain √2 for relu (``torch.nn.init.kaiming_normal_``)."""
    fan_in, fan_out = _fans(t.shape)
    gain = math.sqrt(2.0) if nonlinearity == "relu" else 1.0
    std = gain / math.sqrt(fan_in if mode == "fan_in" else fan_out)
    t.data[...] = default_generator().normal(0.0, std, size=t.shape)
    return t


def uniform_(t: Tensor, low: float, high: float) -> Tensor:
    t.data[...] = default_generator().uniform(low, high, size=t.shape)
    return t


def constant_(t: Tensor, value: float) -> Tensor:
    t.data[...] = value
    return t


def conv_default_(weight: Tensor, bias: Tensor | None) -> None:
    """torch's Conv2d.reset_parameters: kaiming_uniform(a=√5) on the weight, i.e. U(±1/√fan_in),
    and U(±1/√fan_in) on the bias."""
    bound = 1.0 / math.sqrt(_fans(weight.shape)[0])
    uniform_(weight, -bound, bound)
    if bias is not None:
        uniform_(bias, -bound, bound)
