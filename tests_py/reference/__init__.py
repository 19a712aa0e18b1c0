"""Independent PyTorch reference implementation of MIPNet (ground truth for the parity tests).

Built from torch.nn layers only, following docs/architecture.md. It never imports
`mipnet`, so it can be used while the Rust engine is under construction.
"""

from .mipnet_torch import (
    MIPNetTorch,
    bilinear_up4,
    build_ip_stack,
    convex_upsample,
    coords_grid,
    gamma_disp_init,
    ip_correlation,
    rls_correlation,
    sequence_loss_torch,
    warp,
)

__all__ = [
    "MIPNetTorch",
    "bilinear_up4",
    "build_ip_stack",
    "convex_upsample",
    "coords_grid",
    "gamma_disp_init",
    "ip_correlation",
    "rls_correlation",
    "sequence_loss_torch",
    "warp",
]
