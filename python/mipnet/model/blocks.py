"""MIPNet's building blocks (architecture.md §2.2 encoder with iAFF, §2.7 update blocks), on mipnet's engine.

Module and attribute names follow architecture.md §2.10 exactly, so ``state_dict()`` keys equal the canonical
key table (f.2) and weights move unchanged between mipnet and PyTorch.
"""

from __future__ import annotations

from .. import ops
from ..autograd import checkpoint, is_grad_enabled
from ..nn import BatchNorm2d, Conv2d, InstanceNorm2d, Module, Sequential, init
from ..tensor import Tensor

__all__ = ["MSCAMBranch", "MSCAM", "IAFF", "ResBlock", "Stem", "Encoder", "IPMotionEncoder", "RLSMotionEncoder", "ConvGRU",
           "SepConvGRU", "DispHead", "MaskHead", "UpdateBlock", "ip_update_block", "rls_update_block"]


class MSCAMBranch(Module):
    """conv1 1x1 c->c/r, BN, ReLU, conv2 1x1 c/r->c, BN: one branch of MS-CAM (architecture.md §2.2)."""

    def __init__(self, c: int, r: int = 4):
        super().__init__()
        self.conv1 = Conv2d(c, c // r, 1)
        self.bn1 = BatchNorm2d(c // r)
        self.conv2 = Conv2d(c // r, c, 1)
        self.bn2 = BatchNorm2d(c)

    def forward(self, z: Tensor) -> Tensor:
        if self.bn1.training or self.bn2.training:
            return self.bn2(self.conv2(ops.relu(self.bn1(self.conv1(z)))))
        # eval-mode normalisations folded into their convolutions (no pass of their own), the ReLU
        # in the first convolution's epilogue
        (w1, b1), (w2, b2) = self.bn1.folded(self.conv1), self.bn2.folded(self.conv2)
        hidden = ops.conv2d_relu(z, w1, b1, self.conv1.stride, self.conv1.padding)
        return ops.conv2d(hidden, w2, b2, self.conv2.stride, self.conv2.padding)


class MSCAM(Module):
    """Multi-scale channel attention: M(Z) = sigmoid(L(Z) + G(GAP(Z))), broadcast over H, W."""

    def __init__(self, c: int, r: int = 4):
        super().__init__()
        self.local = MSCAMBranch(c, r)
        self.add_module("global", MSCAMBranch(c, r))

    def logits(self, z: Tensor) -> tuple[Tensor, Tensor]:
        """(L(Z), G(GAP(Z))): the local (N, C, H, W) and global (N, C, 1, 1) terms before the sigmoid."""
        return self.local(z), getattr(self, "global")(ops.mean(z, (2, 3), keepdim=True))

    def forward(self, z: Tensor) -> Tensor:
        local, glob = self.logits(z)
        return ops.sigmoid(local + glob)


class IAFF(Module):
    """Two-stage iterative attentional feature fusion with two independent MS-CAMs (MXNet semantics):
    W1 = M1(X + Y); Z1 = W1 X + (1 - W1) Y; W2 = M2(Z1); out = W2 X + (1 - W2) Y."""

    def __init__(self, c: int, r: int = 4):
        super().__init__()
        self.att1 = MSCAM(c, r)
        self.att2 = MSCAM(c, r)

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        # each gate w x + (1 - w) y with w = M(.) is one fused kernel (sigmoid included)
        z1 = ops.attention_gate(*self.att1.logits(x + y), x, y)
        return ops.attention_gate(*self.att2.logits(z1), x, y)


class ResBlock(Module):
    """DIP residual block with instance norm, an always-present 1x1 projection, and iAFF fusion:
    out = ReLU(iAFF(y, x')) (or ReLU(x' + y) without AFF)."""

    def __init__(self, cin: int, cout: int, stride: int, use_aff: bool):
        super().__init__()
        self.conv1 = Conv2d(cin, cout, 3, stride=stride, padding=1)
        self.conv2 = Conv2d(cout, cout, 3, padding=1)
        self.proj = Conv2d(cin, cout, 1, stride=stride)
        self.norm1, self.norm2, self.norm3 = InstanceNorm2d(cout), InstanceNorm2d(cout), InstanceNorm2d(cout)
        if use_aff:
            self.fuse = IAFF(cout)
        self.use_aff = use_aff

    def forward(self, x: Tensor) -> Tensor:
        y = ops.relu(self.norm1(self.conv1(x)))
        y = ops.relu(self.norm2(self.conv2(y)))
        xp = self.norm3(self.proj(x))
        if not self.use_aff:
            return ops.relu(xp + y)
        # iAFF's activations (about 9 maps of cout channels) are recomputed in the backward instead of
        # kept: its 1x1 convolutions and gates cost little next to the block's 3x3 convolutions
        return ops.relu(checkpoint(self.fuse, y, xp, modules=(self.fuse,)))


class Stem(Module):
    """Conv 7x7 stride 2, instance norm, ReLU."""

    def __init__(self):
        super().__init__()
        self.conv = Conv2d(3, 64, 7, stride=2, padding=3)
        self.norm = InstanceNorm2d(64)

    def forward(self, x: Tensor) -> Tensor:
        return ops.relu(self.norm(self.conv(x)))


class Encoder(Module):
    """BasicEncoderQuarter with iAFF: (B,3,H,W) -> (B,256,H/4,W/4) (architecture.md §2.2)."""

    def __init__(self, use_aff: bool = True):
        super().__init__()
        self.stem = Stem()
        self.layer1 = Sequential(ResBlock(64, 64, 1, use_aff), ResBlock(64, 64, 1, use_aff))
        self.layer2 = Sequential(ResBlock(64, 96, 2, use_aff), ResBlock(96, 96, 1, use_aff))
        self.layer3 = Sequential(ResBlock(96, 128, 1, use_aff), ResBlock(128, 128, 1, use_aff))
        self.out = Conv2d(128, 256, 1)
        backbone = [self.stem.conv, self.out] + [c for layer in (self.layer1, self.layer2, self.layer3)
                                                 for blk in layer.children() for c in (blk.conv1, blk.conv2, blk.proj)]
        for conv in backbone:
            init.kaiming_normal_(conv.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: Tensor) -> Tensor:
        return self.out(self.layer3(self.layer2(self.layer1(self.stem(x)))))


class IPMotionEncoder(Module):
    """DIP SmallMotionEncoder: corr (10) and flow (2) -> 94 motion channels before their ReLU; DIP
    applies it and appends the flow (96 channels), which :class:`UpdateBlock` does when it assembles
    the GRU input."""

    def __init__(self, corr_channels: int):
        super().__init__()
        self.corr1 = Conv2d(corr_channels, 96, 1)
        self.flow1 = Conv2d(2, 64, 5, padding=2)
        self.flow2 = Conv2d(64, 32, 3, padding=1)
        self.out = Conv2d(128, 94, 3, padding=1)

    def forward(self, flow: Tensor, corr: Tensor) -> Tensor:
        ab = ops.cat_relu([self.corr1(corr), self.flow2(self.flow1.forward_relu(flow))], [True, True], 1)
        return self.out(ab)


class RLSMotionEncoder(Module):
    """DIP BasicMotionEncoder: corr (21) and flow (2) -> 126 motion channels before their ReLU (128
    with the flow; :class:`UpdateBlock` applies the ReLU and appends the flow)."""

    def __init__(self, corr_channels: int):
        super().__init__()
        self.corr1 = Conv2d(corr_channels, 64, 1)
        self.corr2 = Conv2d(64, 128, 3, padding=1)
        self.flow1 = Conv2d(2, 64, 5, padding=2)
        self.flow2 = Conv2d(64, 64, 3, padding=1)
        self.out = Conv2d(192, 126, 3, padding=1)

    def forward(self, flow: Tensor, corr: Tensor) -> Tensor:
        a = self.corr2(self.corr1.forward_relu(corr))
        b = self.flow2(self.flow1.forward_relu(flow))
        return self.out(ops.cat_relu([a, b], [True, True], 1))


def _stacked_zr(owner: Module, convz: Conv2d, convr: Conv2d) -> tuple[Tensor, Tensor]:
    """convz's and convr's weights and biases stacked along the output channels. While gradients are
    recorded, one stack serves every call of a forward pass (each call's convolution would otherwise
    keep its own copy for the backward); it is rebuilt once its backward has run or the weights are
    new arrays (an optimiser step)."""
    params = (convz.weight, convr.weight, convz.bias, convr.bias)
    key = tuple(id(p.data) for p in params)
    cache = owner.__dict__.setdefault("_zr_stack", {})
    hit = cache.get(id(convz))
    if hit is not None and hit[0] == key and all(t._node is not None and t._node.fn is not None for t in hit[1]):
        return hit[1]
    stack = (ops.cat([convz.weight, convr.weight], 0), ops.cat([convz.bias, convr.bias], 0))
    if is_grad_enabled() and all(t._node is not None for t in stack):
        cache[id(convz)] = (key, stack)
    else:
        cache.pop(id(convz), None)
    return stack


def _gru_pass(owner: Module, convz: Conv2d, convr: Conv2d, convq: Conv2d, hx: Tensor, keep_x: bool) -> Tensor:
    """One GRU pass on hx = [h, x]: z = σ(Wz hx); r = σ(Wr hx); q = tanh(Wq [r h, x]);
    h' = (1 - z) h + z q. z and r come from one convolution (convz's and convr's weights stacked
    along the output channels: one GEMM), the gate arithmetic from two fused kernels; [r h, x] is
    rebuilt in the backward rather than kept. Returns h', or [h', x] (the next pass's input) with
    ``keep_x``."""
    w, b = _stacked_zr(owner, convz, convr)
    zr = ops.conv2d(hx, w, b, convz.stride, convz.padding)
    q = ops.gru_candidate(zr, hx, convq.weight, convq.bias, convq.padding)
    return ops.gru_update(zr, q, hx, keep_x)


class ConvGRU(Module):
    """3x3 convolutional GRU (paper §3.2.2). ``forward(hx)`` takes hx = cat[h, x], returns h'."""

    def __init__(self, hidden: int, inp: int):
        super().__init__()
        self.convz = Conv2d(hidden + inp, hidden, 3, padding=1)
        self.convr = Conv2d(hidden + inp, hidden, 3, padding=1)
        self.convq = Conv2d(hidden + inp, hidden, 3, padding=1)

    def forward(self, hx: Tensor) -> Tensor:
        return _gru_pass(self, self.convz, self.convr, self.convq, hx, keep_x=False)


class SepConvGRU(Module):
    """Separable GRU: a (1,5) horizontal pass, then a (5,1) vertical pass (DIP/RAFT), both on the same x.
    ``forward(hx)`` takes hx = cat[h, x], returns h'."""

    def __init__(self, hidden: int, inp: int):
        super().__init__()
        c = hidden + inp
        self.convz_h = Conv2d(c, hidden, (1, 5), padding=(0, 2))
        self.convr_h = Conv2d(c, hidden, (1, 5), padding=(0, 2))
        self.convq_h = Conv2d(c, hidden, (1, 5), padding=(0, 2))
        self.convz_v = Conv2d(c, hidden, (5, 1), padding=(2, 0))
        self.convr_v = Conv2d(c, hidden, (5, 1), padding=(2, 0))
        self.convq_v = Conv2d(c, hidden, (5, 1), padding=(2, 0))

    def forward(self, hx: Tensor) -> Tensor:
        hx = _gru_pass(self, self.convz_h, self.convr_h, self.convq_h, hx, keep_x=True)
        return _gru_pass(self, self.convz_v, self.convr_v, self.convq_v, hx, keep_x=False)


class DispHead(Module):
    """Delta = conv2(ReLU(conv1(h))): the (Δx, Δy) update."""

    def __init__(self, hidden: int, mid: int):
        super().__init__()
        self.conv1 = Conv2d(hidden, mid, 3, padding=1)
        self.conv2 = Conv2d(mid, 2, 3, padding=1)

    def forward(self, h: Tensor) -> Tensor:
        return self.conv2(self.conv1.forward_relu(h))


class MaskHead(Module):
    """M = 0.25 · conv2(ReLU(conv1(h))): the 144-channel convex-upsampling mask."""

    def __init__(self, hidden: int):
        super().__init__()
        self.conv1 = Conv2d(hidden, 256, 3, padding=1)
        self.conv2 = Conv2d(256, 144, 1)

    def forward(self, h: Tensor) -> Tensor:
        return self.conv2(self.conv1.forward_relu(h)) * 0.25


class UpdateBlock(Module):
    """motion encoder -> GRU on cat[h; context, motion] -> (h, mask, delta) (architecture.md §2.7)."""

    def __init__(self, motion: Module, gru: Module, head_mid: int, hidden: int = 128):
        super().__init__()
        self.motion = motion
        self.gru = gru
        self.disp_head = DispHead(hidden, head_mid)
        self.mask_head = MaskHead(hidden)

    def forward(self, h: Tensor, context: Tensor, corr: Tensor, flow: Tensor,
                with_mask: bool = True) -> tuple[Tensor, Tensor | None, Tensor]:
        """(h', mask or None when ``with_mask`` is off, delta)."""
        # the GRU input [h, x] with x = [context, ReLU(motion), flow] (architecture.md §2.7), assembled in one copy
        h = self.gru(ops.cat_relu([h, context, self.motion(flow, corr), flow], [False, False, True, False], 1))
        return h, self.mask_head(h) if with_mask else None, self.disp_head(h)


def ip_update_block(hidden: int = 128, context: int = 128) -> UpdateBlock:
    """U_IP: DIP SmallUpdateBlock (10 correlation channels, ConvGRU 3x3, 128-channel head)."""
    return UpdateBlock(IPMotionEncoder(10), ConvGRU(hidden, context + 96), 128, hidden)


def rls_update_block(corr_channels: int, hidden: int = 128, context: int = 128) -> UpdateBlock:
    """U_RLS: DIP BasicUpdateBlock (rectangular-search correlation, SepConvGRU, 256-channel head)."""
    return UpdateBlock(RLSMotionEncoder(corr_channels), SepConvGRU(hidden, context + 128), 256, hidden)
