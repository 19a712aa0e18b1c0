"""grid_sample, interpolate (bilinear), unfold and fold.

Kernels: ``grid_sample_fwd`` / ``grid_sample_bwd``, ``interpolate_bilinear_fwd`` / ``interpolate_bilinear_bwd``,
``unfold_fwd`` / ``fold_fwd`` (each the other's backward).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from .. import _core
from ..autograd import Function
from ..errors import ArgumentError, ShapeError
from ..tensor import Tensor
from ._common import as_tensor, pair

__all__ = ["grid_sample", "interpolate", "unfold", "fold"]


# ---- grid_sample ---------------------------------------------------------------------------------

class _GridSample(Function):
    name = "grid_sample"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, grid, padding_mode, align_corners):
        ctx.save_for_backward(x, grid)
        ctx.padding_mode, ctx.align_corners = padding_mode, align_corners
        return _core.grid_sample_fwd(x, grid, padding_mode, align_corners)

    @staticmethod
    def backward(ctx, g):
        x, grid = ctx.saved_tensors
        need_x, need_grid = ctx.needs_input_grad[:2]
        dx, dgrid = _core.grid_sample_bwd(x, grid, g, ctx.padding_mode, ctx.align_corners, need_x, need_grid)
        return dx, dgrid, None, None


def grid_sample(input: Tensor, grid: Tensor, mode: str = "bilinear", padding_mode: str = "zeros",
                align_corners: bool | None = None) -> Tensor:
    """Samples ``input`` bilinearly at the normalised points of ``grid`` (``torch.nn.functional.grid_sample``).

    Parameters
    ----------
    input : Tensor
        (N, C, H, W).
    grid : Tensor
        (N, H_out, W_out, 2): x (width) then y (height), -1 and 1 at the extremes of the input. NaN or
        infinite values raise ``InvalidValueError``.
    mode : {"bilinear"}
        Only bilinear interpolation is implemented.
    padding_mode : {"zeros", "border"}
        Points outside read 0, or are clamped to the border (then the grid gets no gradient).
    align_corners : bool, optional
        True: -1 and 1 are the centres of the corner pixels; False (default, as None in torch): their
        outer edges.

    Shapes
    ------
    input (N, C, H, W), grid (N, H_out, W_out, 2) -> (N, C, H_out, W_out).
    """
    if mode != "bilinear":
        raise ArgumentError(f"grid_sample: unsupported mode {mode!r} (only 'bilinear')")
    if padding_mode not in ("zeros", "border"):
        raise ArgumentError(f"grid_sample: unsupported padding_mode {padding_mode!r} (expected 'zeros' or 'border')")
    x = as_tensor(input)
    return _GridSample.apply(x, as_tensor(grid, x), padding_mode, bool(align_corners))


# ---- interpolate ---------------------------------------------------------------------------------

class _Interpolate(Function):
    name = "interpolate"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, size, align_corners, scales):
        ctx.hw, ctx.align_corners, ctx.scales = tuple(x.shape[-2:]), align_corners, scales
        return _core.interpolate_bilinear_fwd(x, size, align_corners, scales)

    @staticmethod
    def backward(ctx, g):
        return _core.interpolate_bilinear_bwd(g, ctx.hw, ctx.align_corners, ctx.scales), None, None, None


def _pair_of(v: Any, name: str, kind: type) -> tuple:
    if isinstance(v, (list, tuple)):
        if len(v) != 2:
            raise ArgumentError(f"interpolate: {name} must have 2 entries for a 4-D input, got {v!r}")
        return kind(v[0]), kind(v[1])
    return kind(v), kind(v)


def interpolate(input: Tensor, size: int | Sequence[int] | None = None, scale_factor: float | Sequence[float] | None = None,
                mode: str = "nearest", align_corners: bool | None = None, recompute_scale_factor: bool | None = None,
                antialias: bool = False) -> Tensor:
    """Resizes the last two axes of an (N, C, H, W) tensor (``torch.nn.functional.interpolate``).

    Only ``mode="bilinear"`` is implemented; torch's default mode "nearest" therefore raises
    ``ArgumentError`` rather than silently resampling differently.

    Parameters
    ----------
    input : Tensor
        (N, C, H, W).
    size : int or (int, int), optional
        Output (H_out, W_out). Exactly one of ``size`` and ``scale_factor`` is given.
    scale_factor : float or (float, float), optional
        Output size floor(H·s_h), floor(W·s_w). Without align_corners the source coordinates then use
        1/scale_factor, as torch does, unless ``recompute_scale_factor`` is True.
    mode : {"bilinear"}
    align_corners : bool, optional
        True maps corner pixel centres onto each other; False (default) the outer edges.
    recompute_scale_factor : bool, optional
        As torch: True derives the coordinates from the computed output size.
    antialias : bool
        Must be False.

    Shapes
    ------
    (N, C, H, W) -> (N, C, H_out, W_out).
    """
    if mode != "bilinear":
        raise ArgumentError(f"interpolate: unsupported mode {mode!r} (only 'bilinear')")
    if antialias:
        raise ArgumentError("interpolate: antialias=True is not supported")
    if (size is None) == (scale_factor is None):
        raise ArgumentError("interpolate: exactly one of size and scale_factor must be given")
    x = as_tensor(input)
    if x.ndim != 4:
        raise ShapeError(f"interpolate: bilinear mode needs a 4-D (N, C, H, W) input (got input={list(x.shape)})")
    scales: tuple = (None, None)
    if size is not None:
        out = _pair_of(size, "size", int)
    else:
        sf = _pair_of(scale_factor, "scale_factor", float)
        if min(sf) <= 0:
            raise ArgumentError(f"interpolate: scale_factor must be positive, got {scale_factor!r}")
        out = (math.floor(x.shape[2] * sf[0]), math.floor(x.shape[3] * sf[1]))
        if not recompute_scale_factor:
            scales = sf
    if min(out) <= 0:
        raise ShapeError(f"interpolate: output size must be positive (got input={list(x.shape)}, size={list(out)})")
    return _Interpolate.apply(x, out, bool(align_corners), scales)


# ---- unfold / fold -------------------------------------------------------------------------------

def _geometry(op: str, kernel_size: Any, dilation: Any, padding: Any, stride: Any) -> tuple:
    geo = tuple(pair(v, name, op) for v, name in
                ((kernel_size, "kernel_size"), (dilation, "dilation"), (padding, "padding"), (stride, "stride")))
    for (a, b), name, low in zip(geo, ("kernel_size", "dilation", "padding", "stride"), (1, 1, 0, 1)):
        if a < low or b < low:
            raise ArgumentError(f"{op}: {name} must be >= {low}, got {(a, b)}")
    return geo


class _Unfold(Function):
    name = "unfold"
    fresh_grads = True

    @staticmethod
    def forward(ctx, x, geo):
        ctx.unbatched = x.ndim == 3
        x4 = x[None] if ctx.unbatched else x
        ctx.hw, ctx.geo = tuple(x4.shape[-2:]), geo
        cols = _core.unfold_fwd(x4, *geo)
        return cols[0] if ctx.unbatched else cols

    @staticmethod
    def backward(ctx, g):
        # the adjoint of unfold is fold
        dx = _core.fold_fwd(g[None] if ctx.unbatched else g, ctx.hw, *ctx.geo)
        return (dx[0] if ctx.unbatched else dx), None


class _Fold(Function):
    name = "fold"
    fresh_grads = True

    @staticmethod
    def forward(ctx, cols, output_size, geo):
        ctx.unbatched = cols.ndim == 2
        c3 = cols[None] if ctx.unbatched else cols
        ctx.geo = geo
        y = _core.fold_fwd(c3, output_size, *geo)
        return y[0] if ctx.unbatched else y

    @staticmethod
    def backward(ctx, g):
        # the adjoint of fold is unfold
        dc = _core.unfold_fwd(g[None] if ctx.unbatched else g, *ctx.geo)
        return (dc[0] if ctx.unbatched else dc), None, None


def unfold(input: Tensor, kernel_size: int | Sequence[int], dilation: int | Sequence[int] = 1,
           padding: int | Sequence[int] = 0, stride: int | Sequence[int] = 1) -> Tensor:
    """Sliding blocks as columns (``torch.nn.functional.unfold``), zero padding.

    Shapes
    ------
    (N, C, H, W) -> (N, C·kh·kw, L) with L = L_h·L_w, L_h = (H + 2p_h - d_h(k_h - 1) - 1) // s_h + 1;
    an unbatched (C, H, W) input gives (C·kh·kw, L). Row (c·kh + i)·kw + j, column l_h·L_w + l_w.
    """
    return _Unfold.apply(as_tensor(input), _geometry("unfold", kernel_size, dilation, padding, stride))


def fold(input: Tensor, output_size: int | Sequence[int], kernel_size: int | Sequence[int], dilation: int | Sequence[int] = 1,
         padding: int | Sequence[int] = 0, stride: int | Sequence[int] = 1) -> Tensor:
    """Sums columns of sliding blocks into an image (``torch.nn.functional.fold``); the adjoint of ``unfold``.

    Shapes
    ------
    (N, C·kh·kw, L) -> (N, C, H, W) for ``output_size`` (H, W); an unbatched (C·kh·kw, L) input gives (C, H, W).
    """
    out = pair(output_size, "output_size", "fold")
    if min(out) < 1:
        raise ArgumentError(f"fold: output_size must be positive, got {out}")
    return _Fold.apply(as_tensor(input), out, _geometry("fold", kernel_size, dilation, padding, stride))
