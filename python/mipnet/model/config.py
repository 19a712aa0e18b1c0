"""The model's configuration: the architecture switches of the paper's ablations and the input size rules.

Kept apart from the network so that the memory estimate and the weights' metadata can read a config
without building a network (docs/architecture.md §2).
"""

from __future__ import annotations

import dataclasses
import json

from ..errors import ArgumentError

__all__ = ["MIPNetConfig", "DIVISOR", "MIN_SIZE"]

DIVISOR = 16  # H and W of the padded input must be multiples of 16 (stride 4 encoder x 4x4 pooling)
MIN_SIZE = 32


@dataclasses.dataclass(frozen=True)
class MIPNetConfig:
    """The architecture switches of the paper's ablations (Table 1, Table 2) and the gamma init."""

    use_aff: bool = True
    use_ip: bool = True
    use_rls: bool = True
    rx: int = 3
    ry: int = 1
    vertical_constraint: bool = True
    gamma_shape: float = 2.0
    gamma_scale: float = 16.0
    max_disp_init: float = 192.0

    def __post_init__(self) -> None:
        if not (self.use_ip or self.use_rls):
            raise ArgumentError("MIPNet: at least one of use_ip / use_rls must be on")
        if self.rx < 0 or self.ry < 0:
            raise ArgumentError(f"MIPNet: rx and ry must be >= 0, got rx={self.rx}, ry={self.ry}")
        if self.gamma_shape <= 0 or self.gamma_scale <= 0 or self.max_disp_init <= 0:
            raise ArgumentError("MIPNet: gamma_shape, gamma_scale and max_disp_init must be positive")

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)
