"""MIPNet's eval forward written as ONNX nodes, module by module in the order of ``MIPNet.forward``
(``mipnet/model/network.py``; the layers as docs/architecture.md §2 describes them).

Each emitter mirrors one module or step of the network: the encoder (§2.2), the split and pyramid, the
initial field (§2.4), the update blocks and their GRUs (§2.7), the correlations (§2.5, §2.6,
:mod:`.correlation`), the convex and bilinear upsampling (§2.8) and the iteration schedule (§2.9). Every
parameter and BatchNorm statistic becomes an initializer named by its canonical key (§2.10); nothing is
folded or fused, so that a runtime's own optimiser does that and a reader sees the network's own layers.
"""

from __future__ import annotations

import numpy as np

from ..model.blocks import ConvGRU, IPMotionEncoder, ResBlock, UpdateBlock
from ..model.config import DIVISOR
from ..model.network import MIPNet
from ..nn import BatchNorm2d, Conv2d, InstanceNorm2d
from .correlation import level_operands
from .graph import GraphBuilder

__all__ = ["NetworkGraph"]

#: channels of the encoder's output F (architecture.md §2.2) and of the hidden state and context (its halves)
FEATURES, HIDDEN = 256, 128
#: convex upsampling rate and the 3x3 neighbourhood it weighs (architecture.md §2.8)
RATE, NEIGHBOURS = 4, 9


def _pair(value) -> tuple[int, int]:
    """(a, b) of a Conv2d's stride or padding, given as an int or a pair."""
    return (int(value), int(value)) if np.isscalar(value) else (int(value[0]), int(value[1]))


class NetworkGraph:
    """Writes the eval forward of ``model`` into ``builder``.

    Parameters
    ----------
    builder : GraphBuilder
        The graph being built.
    model : MIPNet
        The network whose modules and weights are written (its config picks the blocks and the warp).
    """

    def __init__(self, builder: GraphBuilder, model: MIPNet):
        self.b, self.model, self.cfg = builder, model, model.config
        self._names = {id(m): name for name, m in model.named_modules()}

    # ---- parameters and layers ----------------------------------------------------------------------
    def param(self, module, attr: str) -> str:
        """The initializer of ``module.<attr>`` under its canonical name (architecture.md §2.10)."""
        value = getattr(module, attr)
        array = value.data if hasattr(value, "data") else value
        return self.b.initializer(f"{self._names[id(module)]}.{attr}", np.asarray(array, dtype=np.float32))

    def conv(self, x: str, conv: Conv2d, relu: bool = False) -> str:
        """Conv (with its bias), optionally followed by ReLU."""
        kh, kw = conv.kernel_size
        sh, sw = _pair(conv.stride)
        ph, pw = _pair(conv.padding)
        inputs = [x, self.param(conv, "weight")] + ([self.param(conv, "bias")] if conv.bias is not None else [])
        name = self._names[id(conv)].rsplit(".", 1)[-1]
        y = self.b.op("Conv", inputs, name, kernel_shape=[kh, kw], strides=[sh, sw], pads=[ph, pw, ph, pw])
        return self.b.op("Relu", [y]) if relu else y

    def batch_norm(self, x: str, bn: BatchNorm2d) -> str:
        """Eval-mode BatchNorm: the running statistics (architecture.md §2.2)."""
        inputs = [x] + [self.param(bn, a) for a in ("weight", "bias", "running_mean", "running_var")]
        return self.b.op("BatchNormalization", inputs, self._names[id(bn)].rsplit(".", 1)[-1], epsilon=float(bn.eps))

    def instance_norm(self, x: str, norm: InstanceNorm2d) -> str:
        """Instance norm without affine parameters (scale 1, bias 0)."""
        c = norm.num_features
        return self.b.op("InstanceNormalization", [x, self.b.const(np.ones(c), np.float32),
                                                   self.b.const(np.zeros(c), np.float32)], epsilon=float(norm.eps))

    # ---- encoder (architecture.md §2.2) -----------------------------------------------------------------
    def encoder(self, images: str) -> str:
        """(2N, 3, H, W) normalised, padded images -> F (2N, 256, H/4, W/4)."""
        enc, b = self.model.encoder, self.b
        with b.scope("encoder.stem"):
            x = b.op("Relu", [self.instance_norm(self.conv(images, enc.stem.conv), enc.stem.norm)])
        for layer in ("layer1", "layer2", "layer3"):
            for k, block in enumerate(getattr(enc, layer).children()):
                with b.scope(f"encoder.{layer}.{k}"):
                    x = self.res_block(x, block)
        with b.scope("encoder.out"):
            return self.conv(x, enc.out)

    def res_block(self, x: str, block: ResBlock) -> str:
        """out = ReLU(iAFF(y, x')) or ReLU(x' + y): y the two 3x3 convolutions, x' the projection."""
        b = self.b
        y = b.op("Relu", [self.instance_norm(self.conv(x, block.conv1), block.norm1)])
        y = b.op("Relu", [self.instance_norm(self.conv(y, block.conv2), block.norm2)])
        xp = self.instance_norm(self.conv(x, block.proj), block.norm3)
        if not block.use_aff:
            return b.op("Relu", [b.op("Add", [xp, y])])
        with b.scope("fuse"):
            # iAFF: Z1 = gate(M1(X + Y)); out = gate(M2(Z1)), with X = y and Y = x'
            z1 = self.attention_gate(block.fuse.att1, b.op("Add", [y, xp]), y, xp)
            return b.op("Relu", [self.attention_gate(block.fuse.att2, z1, y, xp)])

    def attention_gate(self, att, z: str, x: str, y: str) -> str:
        """w X + (1 - w) Y with w = sigmoid(L(Z) + G(GAP(Z))) (MS-CAM's weights as iAFF's gate)."""
        b = self.b
        local = self.mscam_branch(att.local, z)
        glob = self.mscam_branch(getattr(att, "global"), b.op("GlobalAveragePool", [z]))
        w = b.op("Sigmoid", [b.op("Add", [local, glob])], "w")
        one_minus_w = b.op("Sub", [b.const(1.0, np.float32), w])
        return b.op("Add", [b.op("Mul", [w, x]), b.op("Mul", [one_minus_w, y])], "gate")

    def mscam_branch(self, branch, z: str) -> str:
        """conv1 1x1, BN, ReLU, conv2 1x1, BN."""
        hidden = self.b.op("Relu", [self.batch_norm(self.conv(z, branch.conv1), branch.bn1)])
        return self.batch_norm(self.conv(hidden, branch.conv2), branch.bn2)

    # ---- update blocks (architecture.md §2.7) -----------------------------------------------------------
    def motion(self, encoder, flow: str, corr: str) -> str:
        """The motion features before their ReLU: IP's 94 or RLS's 126 channels."""
        b = self.b
        with b.scope("motion"):
            if isinstance(encoder, IPMotionEncoder):
                c = self.conv(corr, encoder.corr1, relu=True)
            else:
                c = b.op("Relu", [self.conv(self.conv(corr, encoder.corr1, relu=True), encoder.corr2)])
            f = b.op("Relu", [self.conv(self.conv(flow, encoder.flow1, relu=True), encoder.flow2)])
            return self.conv(b.op("Concat", [c, f], axis=1), encoder.out)

    def gru_pass(self, convz: Conv2d, convr: Conv2d, convq: Conv2d, h: str, x: str) -> str:
        """z = σ(Wz [h, x]); r = σ(Wr [h, x]); q = tanh(Wq [r h, x]); h' = (1 - z) h + z q."""
        b = self.b
        hx = b.op("Concat", [h, x], "hx", axis=1)
        z = b.op("Sigmoid", [self.conv(hx, convz)], "z")
        r = b.op("Sigmoid", [self.conv(hx, convr)], "r")
        q = b.op("Tanh", [self.conv(b.op("Concat", [b.op("Mul", [r, h]), x], axis=1), convq)], "q")
        keep = b.op("Mul", [b.op("Sub", [b.const(1.0, np.float32), z]), h])
        return b.op("Add", [keep, b.op("Mul", [z, q])], "h")

    def gru(self, gru, h: str, x: str) -> str:
        """ConvGRU (3x3) or SepConvGRU (a 1x5 pass, then a 5x1 pass on the same x)."""
        with self.b.scope("gru"):
            if isinstance(gru, ConvGRU):
                return self.gru_pass(gru.convz, gru.convr, gru.convq, h, x)
            h = self.gru_pass(gru.convz_h, gru.convr_h, gru.convq_h, h, x)
            return self.gru_pass(gru.convz_v, gru.convr_v, gru.convq_v, h, x)

    def update_block(self, block: UpdateBlock, h: str, context: str, corr: str, flow: str,
                     with_mask: bool) -> tuple[str, str | None, str]:
        """(h', the mask (N, 144, h, w) when ``with_mask``, Δ (N, 2, h, w)) of one sub-update."""
        b = self.b
        # the GRU input x = [context, ReLU(motion), flow]
        x = b.op("Concat", [context, b.op("Relu", [self.motion(block.motion, flow, corr)]), flow], "x", axis=1)
        h = self.gru(block.gru, h, x)
        mask = None
        if with_mask:
            with b.scope("mask_head"):
                head = block.mask_head
                logits = self.conv(self.conv(h, head.conv1, relu=True), head.conv2)
                mask = b.op("Mul", [logits, b.const(0.25, np.float32)], "mask")
        with b.scope("disp_head"):
            delta = self.conv(self.conv(h, block.disp_head.conv1, relu=True), block.disp_head.conv2)
        return h, mask, delta

    # ---- upsampling (architecture.md §2.8) --------------------------------------------------------------
    def convex_upsample(self, flow: str, mask: str, channels: int) -> str:
        """(N, D, h, w) -> (N, D, 4h, 4w): out[d, 4y + i, 4x + j] = Σ_k softmax_k(M[16k + 4i + j]) · 4 f(y + dy_k,
        x + dx_k), f read as 0 outside the map, k = 3 (dy + 1) + (dx + 1)."""
        b = self.b
        with b.scope("convex_upsample"):
            # softmax over k of M viewed as (N, 9, 16·h·w), back to (N, 144, h, w)
            flat = b.op("Reshape", [mask, b.const([0, NEIGHBOURS, -1])])
            weights = b.op("Reshape", [b.op("Softmax", [flat], axis=1), b.op("Shape", [mask])], "weights")
            weight_k = b.split(weights, NEIGHBOURS, axis=1, hint="weight_k")  # each (N, 16, h, w)
            scaled = b.op("Mul", [flow, b.const(float(RATE), np.float32)])
            padded = b.op("Pad", [scaled, b.const([0, 0, 1, 1, 0, 0, 1, 1])], "padded", mode="constant")
            upsampled = []
            for d in range(channels):
                with b.scope(f"channel{d}"):
                    plane = b.op("Slice", [padded, b.const([d]), b.const([d + 1]), b.const([1])])
                    terms = [b.op("Mul", [weight_k[3 * (dy + 1) + (dx + 1)], b.window(plane, [2, 3], [dy, dx], [1, 1])])
                             for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
                    # (N, 16, h, w), channel 4i + j -> (N, 1, 4h, 4w), pixel (4y + i, 4x + j)
                    upsampled.append(b.op("DepthToSpace", [b.op("Sum", terms)], blocksize=RATE, mode="CRD"))
            return upsampled[0] if channels == 1 else b.op("Concat", upsampled, axis=1)

    def prediction(self, flow: str, mask: str, bilinear: int) -> str:
        """Full-resolution positive disparity -f_x: convex x4, then (1/16 level) bilinear x4 (align_corners)."""
        b = self.b
        with b.scope("prediction"):
            fx = b.op("Slice", [flow, b.const([0]), b.const([1]), b.const([1])], "fx")
            up = self.convex_upsample(fx, mask, 1)
            if bilinear > 1:
                scales = b.const([1.0, 1.0, float(bilinear), float(bilinear)], np.float32)
                up = b.op("Resize", [up, "", scales], mode="linear", coordinate_transformation_mode="align_corners")
                up = b.op("Mul", [up, b.const(float(bilinear), np.float32)])
            return b.op("Neg", [up], "disparity")

    # ---- the forward pass -----------------------------------------------------------------------------------
    def forward(self, left: str, right: str, initial: str, iters: tuple[int, int]) -> str:
        """The disparity (N, 1, H, W) of the pair ``left``, ``right`` (N, 3, H, W), 0..255. ``initial`` is
        the 1/16-level initial disparity d0, (N, 1, H16, W16) or (1, 1, H16, W16) (then the same for every
        pair of the batch, as the seeded eval draw), in 1/16-level pixels (architecture.md §2.4)."""
        b = self.b
        n16, n4 = iters
        with b.scope("input"):
            images = b.op("Concat", [left, right], "images", axis=0)
            # I' = 2 (I / 255) - 1 (architecture.md §2.1)
            scaled = b.op("Div", [images, b.const(255.0, np.float32)])
            normalised = b.op("Sub", [b.op("Mul", [scaled, b.const(2.0, np.float32)]), b.const(1.0, np.float32)])
            height, width = b.dim(left, 2, "H"), b.dim(left, 3, "W")
            (top, bottom), (lft, rgt) = (self._pad_split(height, "ph"), self._pad_split(width, "pw"))
            zero = b.const([0])
            pads = b.op("Concat", [zero, zero, top, lft, zero, zero, bottom, rgt], "pads", axis=0)
            padded = b.op("Pad", [normalised, pads], "padded", mode="edge")
        features = self.encoder(padded)
        with b.scope("pyramid"):
            fl4, fr4 = b.split(features, 2, axis=0, hint="split")
            hidden4 = b.op("Tanh", [b.op("Slice", [fl4, b.const([0]), b.const([HIDDEN]), b.const([1])])], "hidden4")
            context4 = b.op("Relu", [b.op("Slice", [fl4, b.const([HIDDEN]), b.const([FEATURES]), b.const([1])])], "context4")
            fl16, fr16, hidden16, context16 = (b.op("AveragePool", [t], name, kernel_shape=[4, 4], strides=[4, 4])
                                               for t, name in ((fl4, "fl16"), (fr4, "fr16"), (hidden4, "hidden16"),
                                                               (context4, "context16")))
            # (N, 1, 1, 1) -> the initial disparity for every pair; f16 = (-d0, 0)
            batch = b.op("Concat", [b.op("Shape", [fl16], start=0, end=1), b.const([1, 1, 1])], axis=0)
            d0 = b.op("Expand", [initial, batch], "d0")
            flow16 = b.op("Mul", [d0, b.const(np.array([-1.0, 0.0]).reshape(1, 2, 1, 1), np.float32)], "flow16")
        with b.scope("level16"):
            flow, mask = self.iterate(fl16, fr16, hidden16, context16, flow16, n16)
        if n4 == 0:
            pred = self.prediction(flow, mask, RATE)
        else:
            with b.scope("handover"):
                flow4 = self.convex_upsample(flow, mask, 2)
            with b.scope("level4"):
                flow, mask = self.iterate(fl4, fr4, hidden4, context4, flow4, n4)
            pred = self.prediction(flow, mask, 1)
        with b.scope("crop"):
            starts = b.op("Concat", [top, lft], axis=0)
            ends = b.op("Concat", [b.op("Add", [top, b.op("Unsqueeze", [height, zero])]),
                                   b.op("Add", [lft, b.op("Unsqueeze", [width, zero])])], axis=0)
            return b.op("Slice", [pred, starts, ends, b.const([2, 3])], "disparity")

    def _pad_split(self, length: str, hint: str) -> tuple[str, str]:
        """(before, after) as 1-D int64: the replicate padding of ``length`` to a multiple of 16, split as
        ``_padding`` splits it: p = -L mod 16, before = p // 2, after = p - before (architecture.md §2.1)."""
        b = self.b
        # p = ceil(L / 16)·16 - L = ((L + 15) // 16)·16 - L (integer Div floors for positive operands)
        rounded = b.op("Mul", [b.op("Div", [b.op("Add", [length, b.const(DIVISOR - 1)]), b.const(DIVISOR)]), b.const(DIVISOR)])
        total = b.op("Sub", [rounded, length], hint)
        before = b.op("Div", [total, b.const(2)])
        return (b.op("Unsqueeze", [before, b.const([0])], f"{hint}_before"),
                b.op("Unsqueeze", [b.op("Sub", [total, before]), b.const([0])], f"{hint}_after"))

    def iterate(self, fl: str, fr: str, hidden: str, context: str, flow: str, iters: int) -> tuple[str, str]:
        """``iters`` IPM iterations at one level (IP then RLS each, architecture.md §2.9): the last flow and
        the mask of the last sub-update."""
        b, cfg = self.b, self.cfg
        operands = level_operands(b, fl, fr, FEATURES, cfg)
        blocks = [(name, getattr(self.model, "update_" + name)) for name, on in (("ip", cfg.use_ip), ("rls", cfg.use_rls)) if on]
        # (Δx, Δy) -> (Δx, 0) under the vertical constraint
        keep = b.const(np.array([1.0, 0.0 if cfg.vertical_constraint else 1.0]).reshape(1, 2, 1, 1), np.float32)
        mask = None
        for t in range(iters):
            for k, (name, block) in enumerate(blocks):
                last = t == iters - 1 and k == len(blocks) - 1
                with b.scope(f"iter{t}.update_{name}"):
                    corr = operands.correlation(name, flow)
                    hidden, step_mask, delta = self.update_block(block, hidden, context, corr, flow, with_mask=last)
                    flow = b.op("Add", [flow, b.op("Mul", [delta, keep])], "flow")
                    mask = step_mask if last else mask
        return flow, mask
