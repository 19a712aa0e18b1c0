"""The IP and RLS correlations of one pyramid level as ONNX nodes (docs/architecture.md §2.3, §2.5, §2.6).

Two warps, as the network has them (``mipnet.model.network._CorrelationOperands``):

* :class:`HorizontalGatherOperands` (``vertical_constraint=True``, the default): the flow's f_y is 0, so the
  warp is a linear interpolation along the row, X = clamp(x + f_x, 0, w - 1), x0 = floor(X),
  x1 = min(x0 + 1, w - 1), a = X - x0, read with ``Gather`` from the channels-last right features
  flattened to (N·h·w, C), as mipnet's fused kernels read them (§2.3);
* :class:`GridSampleOperands` (``vertical_constraint=False``): the general warp, ``GridSample``
  (bilinear, border, align_corners) on the sampling grid p + f(p) normalised as §2.3 writes it, of the
  IP seed stack and of the right features.

Both hand the warped maps, channels-last (N, h, w, C), to the same correlation tails
(:func:`ip_correlation`, :func:`rls_correlation`). Every size the nodes need is computed in the graph
from the features' shapes, so the same graph serves a fixed and a dynamic input size.
"""

from __future__ import annotations

import abc

from ..model.config import MIPNetConfig
from ..ops import IP_SEEDS
from .graph import FLOAT, INT64, GraphBuilder

__all__ = ["ip_correlation", "rls_correlation", "LevelOperands", "HorizontalGatherOperands", "GridSampleOperands",
           "level_operands", "IP_GROUPS"]

#: Channel groups of the IP correlation (architecture.md §2.5).
IP_GROUPS = 2


def ip_correlation(b: GraphBuilder, fl_nhwc: str, warped_seeds: list[str], channels: int) -> str:
    """C_IP (N, G·S, h, w) from F_L and the S warped seed maps, all channels-last (N, h, w, C):
    out[S·g + s] = mean over group g's C/G channels of F_L · W(S_s) (architecture.md §2.5)."""
    per_seed = []
    for s, warped in enumerate(warped_seeds):
        with b.scope(f"seed{s}"):
            grouped = b.op("Reshape", [b.op("Mul", [fl_nhwc, warped]), b.const([0, 0, 0, IP_GROUPS, channels // IP_GROUPS])])
            # (N, h, w, G) -> (N, h, w, G, 1)
            per_seed.append(b.op("Unsqueeze", [b.reduce("ReduceMean", grouped, [4], keepdims=False), b.const([4])]))
    # (N, h, w, G, S) -> (N, h, w, G·S) with channel S·g + s -> (N, G·S, h, w)
    stacked = b.op("Reshape", [b.op("Concat", per_seed, axis=4), b.const([0, 0, 0, IP_GROUPS * len(warped_seeds)])])
    return b.op("Transpose", [stacked], "ip_corr", perm=[0, 3, 1, 2])


def rls_correlation(b: GraphBuilder, fl_nhwc: str, warped: str, rx: int, ry: int) -> str:
    """C_RLS (N, (2rx+1)(2ry+1), h, w) from F_L and W(F_R), channels-last (N, h, w, C): candidate
    (i, j) is channel (2ry+1)·i + j, the channel mean of F_L(y, x) · W(F_R)(clamp(y + j - ry),
    clamp(x + i - rx)) (architecture.md §2.6; the clamp is an edge padding of the warped map)."""
    padded = b.op("Pad", [warped, b.const([0, ry, rx, 0, 0, ry, rx, 0])], "warped_padded", mode="edge")
    candidates = []
    for i in range(2 * rx + 1):
        for j in range(2 * ry + 1):
            with b.scope(f"shift{i}_{j}"):
                shifted = b.window(padded, [1, 2], [j - ry, i - rx], [ry, rx])
                candidates.append(b.reduce("ReduceMean", b.op("Mul", [fl_nhwc, shifted]), [3], keepdims=True))
    return b.op("Transpose", [b.op("Concat", candidates, axis=3)], "rls_corr", perm=[0, 3, 1, 2])


class LevelOperands(abc.ABC):
    """What the correlations of one level read, built once per level: F_L channels-last and the
    warp's own operands. ``correlation(name, flow)`` gives C_IP or C_RLS of the flow (N, 2, h, w)."""

    def __init__(self, b: GraphBuilder, fl: str, fr: str, channels: int, cfg: MIPNetConfig):
        self.b, self.fr, self.channels, self.cfg = b, fr, channels, cfg
        # (N, C, h, w) -> (N, h, w, C)
        self.fl_nhwc = b.op("Transpose", [fl], "fl_nhwc", perm=[0, 2, 3, 1])

    @abc.abstractmethod
    def warped_seeds(self, flow: str) -> list[str]:
        """W(S_s(F_R), f) for every IP seed s, channels-last (N, h, w, C)."""

    @abc.abstractmethod
    def warped_right(self, flow: str) -> str:
        """W(F_R, f), channels-last (N, h, w, C)."""

    def correlation(self, name: str, flow: str) -> str:
        if name == "ip":
            return ip_correlation(self.b, self.fl_nhwc, self.warped_seeds(flow), self.channels)
        return rls_correlation(self.b, self.fl_nhwc, self.warped_right(flow), self.cfg.rx, self.cfg.ry)


class HorizontalGatherOperands(LevelOperands):
    """The horizontal warp of the vertical constraint, by ``Gather`` (architecture.md §2.3, fused path)."""

    def __init__(self, b: GraphBuilder, fl: str, fr: str, channels: int, cfg: MIPNetConfig):
        super().__init__(b, fl, fr, channels, cfg)
        # F_R (N, C, h, w) -> channels-last, flattened to rows of C: row (n·h + y)·w + x
        fr_nhwc = b.op("Transpose", [fr], "fr_nhwc", perm=[0, 2, 3, 1])
        self.fr_rows = b.op("Reshape", [fr_nhwc, b.const([-1, channels])], "fr_rows")
        n, h, w = b.dim(fl, 0, "n"), b.dim(fl, 2, "h"), b.dim(fl, 3, "w")
        one, zero = b.const(1), b.const(0)
        self.xs = b.op("Cast", [b.op("Range", [zero, w, one])], "xs", to=FLOAT)  # (w,): x
        self.wmax = b.op("Cast", [b.op("Sub", [w, one])], "wmax", to=FLOAT)  # w - 1
        ys, ns, hmax = b.op("Range", [zero, h, one], "ys"), b.op("Range", [zero, n, one], "ns"), b.op("Sub", [h, one])
        image_rows = b.op("Mul", [b.op("Unsqueeze", [ns, b.const([1])]), h], "image_rows")  # (N, 1): n·h
        self.row_base = {}
        for oy in sorted({oy for _, oy in IP_SEEDS}):
            # (N, h, 1, 1): (n·h + clamp(y + oy, 0, h - 1))·w, the first row of seed row oy
            rows = b.clamp(b.op("Add", [ys, b.const(oy)]), zero, hmax, f"rows{oy:+d}")
            base = b.op("Mul", [b.op("Add", [image_rows, rows]), w])
            self.row_base[oy] = b.op("Unsqueeze", [base, b.const([2, 3])], f"row_base{oy:+d}")

    def _taps(self, flow: str) -> tuple[str, str, str]:
        """x0, x1 (N, h, w) and the blend weights (N, h, w, 2, 1) = (1 - a, a) of the flow's footprint."""
        b = self.b
        fx = b.op("Gather", [flow, b.const(0)], "fx", axis=1)  # (N, h, w)
        zero = b.const(0.0, "float32")
        x = b.clamp(b.op("Add", [self.xs, fx]), zero, self.wmax, "X")  # X = clamp(x + f_x, 0, w - 1)
        x0 = b.op("Floor", [x], "x0")
        a = b.op("Sub", [x, x0], "a")
        x1 = b.op("Min", [b.op("Add", [x0, b.const(1.0, "float32")]), self.wmax], "x1")  # min(x0 + 1, w - 1)
        last = b.const([-1])
        pair = b.op("Concat", [b.op("Unsqueeze", [b.op("Sub", [b.const(1.0, "float32"), a]), last]),
                               b.op("Unsqueeze", [a, last])], axis=-1)
        return x0, x1, b.op("Unsqueeze", [pair, last], "blend")

    def _warp(self, taps: tuple[str, str, str], ox: int, oy: int) -> str:
        """(1 - a)·F_R(clamp(y + oy), clamp(x0 + ox)) + a·F_R(clamp(y + oy), clamp(x1 + ox)), (N, h, w, C)."""
        b = self.b
        x0, x1, blend = taps
        zero, last = b.const(0.0, "float32"), b.const([-1])
        cols = [b.op("Unsqueeze", [b.clamp(b.op("Add", [x, b.const(float(ox), "float32")]), zero, self.wmax), last])
                for x in (x0, x1)]
        # row of F_R's flattened map: (n·h + clamp(y + oy))·w + column, (N, h, w, 2)
        index = b.op("Add", [self.row_base[oy], b.op("Cast", [b.op("Concat", cols, axis=-1)], to=INT64)], "index")
        gathered = b.op("Gather", [self.fr_rows, index], "taps", axis=0)  # (N, h, w, 2, C)
        return b.reduce("ReduceSum", b.op("Mul", [gathered, blend]), [3], keepdims=False, hint="warped")

    def warped_seeds(self, flow: str) -> list[str]:
        taps = self._taps(flow)
        out = []
        for s, (ox, oy) in enumerate(IP_SEEDS):
            with self.b.scope(f"seed{s}"):
                out.append(self._warp(taps, ox, oy))
        return out

    def warped_right(self, flow: str) -> str:
        return self._warp(self._taps(flow), 0, 0)


class GridSampleOperands(LevelOperands):
    """The general warp, by ``GridSample`` of the seed stack and of F_R (architecture.md §2.3, §2.5)."""

    def __init__(self, b: GraphBuilder, fl: str, fr: str, channels: int, cfg: MIPNetConfig):
        super().__init__(b, fl, fr, channels, cfg)
        h, w, one, zero = b.dim(fl, 2, "h"), b.dim(fl, 3, "w"), b.const(1), b.const(0)
        self.xs = b.op("Cast", [b.op("Range", [zero, w, one])], "xs", to=FLOAT)  # (w,): x
        ys = b.op("Cast", [b.op("Range", [zero, h, one])], to=FLOAT)
        self.ys = b.op("Unsqueeze", [ys, b.const([1])], "ys")  # (h, 1): y
        # max(size - 1, 1), the align_corners normaliser
        self.wden = b.op("Cast", [b.op("Max", [b.op("Sub", [w, one]), one])], "wden", to=FLOAT)
        self.hden = b.op("Cast", [b.op("Max", [b.op("Sub", [h, one]), one])], "hden", to=FLOAT)
        if cfg.use_ip:
            # cat[S_0..S_4] (N, 5C, h, w): S_s(y, x) = F_R(clamp(y + oy), clamp(x + ox)) (architecture.md §2.5)
            padded = b.op("Pad", [fr, b.const([0, 0, 1, 1, 0, 0, 1, 1])], "fr_padded", mode="edge")
            shifted = [fr if (ox, oy) == (0, 0) else b.window(padded, [2, 3], [oy, ox], [1, 1], f"seed{s}")
                       for s, (ox, oy) in enumerate(IP_SEEDS)]
            self.stack = b.op("Concat", shifted, "seed_stack", axis=1)

    def _grid(self, flow: str) -> str:
        """(N, h, w, 2): g = 2 (p + f) / max(size - 1, 1) - 1 for x then y (architecture.md §2.3)."""
        b = self.b
        two, one, last = b.const(2.0, "float32"), b.const(1.0, "float32"), b.const([-1])
        coords = []
        for channel, base, den in ((0, self.xs, self.wden), (1, self.ys, self.hden)):
            f = b.op("Gather", [flow, b.const(channel)], axis=1)  # (N, h, w)
            g = b.op("Sub", [b.op("Div", [b.op("Mul", [b.op("Add", [base, f]), two]), den]), one])
            coords.append(b.op("Unsqueeze", [g, last]))
        return b.op("Concat", coords, "grid", axis=-1)

    def _nhwc(self, x: str) -> str:
        return self.b.op("Transpose", [x], perm=[0, 2, 3, 1])

    def warped_seeds(self, flow: str) -> list[str]:
        b = self.b
        warped = b.grid_sample(self.stack, self._grid(flow), "warped_stack")
        c = self.channels
        # seed s: channels [s·C, (s + 1)·C) of the warped stack
        return [self._nhwc(b.op("Slice", [warped, b.const([s * c]), b.const([(s + 1) * c]), b.const([1])], f"seed{s}"))
                for s in range(len(IP_SEEDS))]

    def warped_right(self, flow: str) -> str:
        return self._nhwc(self.b.grid_sample(self.fr, self._grid(flow), "warped"))


def level_operands(b: GraphBuilder, fl: str, fr: str, channels: int, cfg: MIPNetConfig) -> LevelOperands:
    """The operands of the warp the config uses (the network's choice, ``_CorrelationOperands``)."""
    kind = HorizontalGatherOperands if cfg.vertical_constraint else GridSampleOperands
    return kind(b, fl, fr, channels, cfg)
