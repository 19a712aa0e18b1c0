"""PyTorch reference implementation of MIPNet (Leng et al., J. Mar. Sci. Eng. 2023, 11(5), 930).

Written plainly from the network's description, docs/architecture.md; section numbers in the docstrings
refer to it. This module is the ground truth the Rust engine is compared against, so it uses the plain
PyTorch calls literally (grid_sample warp, replicate pad + slicing, RAFT convex upsampling).

Conventions (architecture.md §1): left image is the reference; the network carries a 2-channel flow
f = (f_x, f_y) in pixel units of the current level with f_x = -disparity and f_y = 0; outputs are
positive disparity d = -f_x at full resolution.
"""

from __future__ import annotations

from typing import Callable, List, Optional, Sequence, Tuple, Union

import torch
import torch.nn as nn
import torch.nn.functional as F

HIDDEN_DIM = 128
CONTEXT_DIM = 128
FEATURE_DIM = 256
UPSAMPLE_RATE = 4

# IP seed offsets (ox, oy) in units of the radius r, stack order of architecture.md §2.5: centre, tl, tr, dl, dr.
IP_SEED_OFFSETS: Tuple[Tuple[int, int], ...] = ((0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1))
IP_RADIUS = 1
IP_GROUPS = 2


# ------------------------------------------------------------------------------------------------
# Primitive operations (architecture.md §2.3, §2.5, §2.6, §2.8, §4)
# ------------------------------------------------------------------------------------------------


def coords_grid(n: int, h: int, w: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Pixel coordinate grid (N,2,h,w): channel 0 = column x, channel 1 = row y (architecture.md §2.3, §4)."""
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=dtype, device=device),
        torch.arange(w, dtype=dtype, device=device),
        indexing="ij",
    )
    return torch.stack([xs, ys], dim=0).unsqueeze(0).expand(n, 2, h, w)


def warp(feat: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """W(F, f): sample `feat` at p + f(p) with bilinear grid_sample, border padding (architecture.md §2.3, §4)."""
    n, _, h, w = flow.shape
    coords = coords_grid(n, h, w, flow.dtype, flow.device) + flow
    gx = 2 * coords[:, 0] / max(w - 1, 1) - 1
    gy = 2 * coords[:, 1] / max(h - 1, 1) - 1
    grid = torch.stack([gx, gy], dim=1).permute(0, 2, 3, 1)
    return F.grid_sample(feat, grid, mode="bilinear", padding_mode="border", align_corners=True)


def build_ip_stack(fr: torch.Tensor, radius: int = IP_RADIUS) -> torch.Tensor:
    """Static IP seed stack S = cat[S_0..S_4] (N,5C,h,w), S_s(y,x) = F_R(y+oy, x+ox) clamped (architecture.md §2.5).

    Built once per level: replicate pad by r on every side, then slice one h x w window per seed.
    """
    _, _, h, w = fr.shape
    r = radius
    padded = F.pad(fr, [r, r, r, r], mode="replicate")
    slots = []
    for ox, oy in IP_SEED_OFFSETS:
        # padded[r + dy] holds F_R(y + dy) for the clamped row y + dy (same for columns).
        slots.append(padded[:, :, r + oy * r : r + oy * r + h, r + ox * r : r + ox * r + w])
    return torch.cat(slots, dim=1)


def ip_correlation(fl: torch.Tensor, s_hat: torch.Tensor, groups: int = IP_GROUPS) -> torch.Tensor:
    """IP correlation, semantic layout (architecture.md §2.5): C_IP[5*g + s] = mean_k F_L[g,k] * S_hat[s,g,k].

    `s_hat` is the warped seed stack (N,5C,h,w); the output has 5*groups channels.
    """
    n, c, h, w = fl.shape
    slots = len(IP_SEED_OFFSETS)
    # Stack channel index = s*C + g*(C/groups) + k  ->  axes (slot, group, channel-in-group).
    s_view = s_hat.view(n, slots, groups, c // groups, h, w)
    f_view = fl.view(n, 1, groups, c // groups, h, w)
    corr = (f_view * s_view).mean(dim=3)
    # (N, slot, group, h, w) -> (N, group, slot, h, w) so the flat channel index is 5*g + s.
    return corr.permute(0, 2, 1, 3, 4).reshape(n, groups * slots, h, w)


def rls_correlation(fl: torch.Tensor, wf: torch.Tensor, rx: int, ry: int) -> torch.Tensor:
    """RLS correlation (architecture.md §2.6): C[(2ry+1)*i + j] = mean_c F_L * pad(Wf)[:, :, j:j+h, i:i+w].

    `wf` = W(F_R, f) is the warped right feature map; candidate (i, j) compares F_L(p) with
    Wf(p + (i - rx, j - ry)) (replicate-clamped). Loops are x outer, y inner.
    """
    _, _, h, w = fl.shape
    padded = F.pad(wf, [rx, rx, ry, ry], mode="replicate")
    out = []
    for i in range(2 * rx + 1):
        for j in range(2 * ry + 1):
            out.append((fl * padded[:, :, j : j + h, i : i + w]).mean(dim=1, keepdim=True))
    return torch.cat(out, dim=1)


def convex_upsample(flow: torch.Tensor, mask: torch.Tensor, rate: int = UPSAMPLE_RATE) -> torch.Tensor:
    """Convex x`rate` upsampling exactly as RAFT (architecture.md §2.8): (N,2,h,w) + (N,9*rate^2,h,w) -> (N,2,rh,rw)."""
    n, _, h, w = flow.shape
    # Mask channel k*rate^2 + i*rate + j -> (neighbour k, sub-row i, sub-column j).
    weights = torch.softmax(mask.view(n, 1, 9, rate, rate, h, w), dim=2)
    patches = F.unfold(rate * flow, kernel_size=3, padding=1)
    patches = patches.view(n, 2, 9, 1, 1, h, w)
    up = torch.sum(weights * patches, dim=2)
    # (N,2,i,j,y,x) -> (N,2,y,i,x,j) so that the output row is rate*y + i and column rate*x + j.
    up = up.permute(0, 1, 4, 2, 5, 3)
    return up.reshape(n, 2, rate * h, rate * w)


def bilinear_up4(flow: torch.Tensor) -> torch.Tensor:
    """Bilinear x4 of a flow field, values scaled by 4 (architecture.md §2.8, DIP `upflow4`)."""
    _, _, h, w = flow.shape
    return 4 * F.interpolate(flow, size=(4 * h, 4 * w), mode="bilinear", align_corners=True)


def gamma_disp_init(
    shape: Sequence[int],
    gamma_shape: float = 2.0,
    gamma_scale: float = 16.0,
    max_disp: float = 192.0,
    generator: Optional[torch.Generator] = None,
    seed: Optional[int] = None,
) -> torch.Tensor:
    """Full-resolution initial disparity d0 ~ Gamma(shape, scale) clamped to [0, max_disp] (architecture.md §2.4).

    Drawn on the CPU in float32. Integer shape k: Erlang, d0 = -theta * sum_j ln U_j with
    U_j = 1 - torch.rand(shape, generator) in (0, 1] (U_1 drawn first). Non-integer shape:
    torch.distributions.Gamma, seeded inside `torch.random.fork_rng` when `seed` is given.
    """
    shape = tuple(int(s) for s in shape)
    if float(gamma_shape).is_integer() and gamma_shape >= 1:
        log_sum = torch.zeros(shape, dtype=torch.float32)
        for _ in range(int(gamma_shape)):
            u = 1 - torch.rand(shape, generator=generator, dtype=torch.float32)
            log_sum = log_sum + torch.log(u)
        d0 = -gamma_scale * log_sum
    else:
        dist = torch.distributions.Gamma(
            torch.tensor(float(gamma_shape)), torch.tensor(1.0 / float(gamma_scale))
        )
        if seed is not None:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                d0 = dist.sample(shape)
        else:
            d0 = dist.sample(shape)
    return d0.clamp(0.0, max_disp)


def instance_norm(x: torch.Tensor) -> torch.Tensor:
    """InstanceNorm2d without affine parameters or running stats, eps 1e-5 (architecture.md §2.2, §4)."""
    return F.instance_norm(x, eps=1e-5)


# ------------------------------------------------------------------------------------------------
# Encoder (architecture.md §2.2, module tree f.1)
# ------------------------------------------------------------------------------------------------


class MSCAMBranch(nn.Module):
    """One MS-CAM branch: BN(conv2(ReLU(BN(conv1(z))))), 1x1 convs c -> c/4 -> c (architecture.md §2.2)."""

    def __init__(self, channels: int, reduction: int = 4):
        super().__init__()
        inner = channels // reduction
        self.conv1 = nn.Conv2d(channels, inner, kernel_size=1)
        self.bn1 = nn.BatchNorm2d(inner, eps=1e-5, momentum=0.1)
        self.conv2 = nn.Conv2d(inner, channels, kernel_size=1)
        self.bn2 = nn.BatchNorm2d(channels, eps=1e-5, momentum=0.1)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.bn2(self.conv2(F.relu(self.bn1(self.conv1(z)))))


class MSCAM(nn.Module):
    """Multi-scale channel attention M(Z) = sigmoid(L(Z) + G(GAP(Z))) (architecture.md §2.2)."""

    def __init__(self, channels: int):
        super().__init__()
        self.local = MSCAMBranch(channels)
        # `global` is a Python keyword; the state_dict component stays "global" (architecture.md §2.10).
        self.add_module("global", MSCAMBranch(channels))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        local = self.local(z)
        glob = getattr(self, "global")(z.mean(dim=(2, 3), keepdim=True))
        return torch.sigmoid(local + glob)


class IAFF(nn.Module):
    """Iterative attentional feature fusion with two independent MS-CAMs (architecture.md §2.2, MXNet semantics)."""

    def __init__(self, channels: int):
        super().__init__()
        self.att1 = MSCAM(channels)
        self.att2 = MSCAM(channels)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        w1 = self.att1(x + y)
        z1 = w1 * x + (1 - w1) * y
        w2 = self.att2(z1)
        return w2 * x + (1 - w2) * y


class ResBlock(nn.Module):
    """DIP ResidualBlock with instance norm, always-on 1x1 projection, iAFF fusion (architecture.md §2.2)."""

    def __init__(self, cin: int, cout: int, stride: int, use_aff: bool):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, kernel_size=3, stride=stride, padding=1)
        self.conv2 = nn.Conv2d(cout, cout, kernel_size=3, stride=1, padding=1)
        self.proj = nn.Conv2d(cin, cout, kernel_size=1, stride=stride, padding=0)
        self.fuse = IAFF(cout) if use_aff else None

    def backbone_convs(self) -> List[nn.Conv2d]:
        return [self.conv1, self.conv2, self.proj]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(instance_norm(self.conv1(x)))
        y = F.relu(instance_norm(self.conv2(y)))
        identity = instance_norm(self.proj(x))
        if self.fuse is None:
            return F.relu(identity + y)
        return F.relu(self.fuse(y, identity))


class Stem(nn.Module):
    """Conv 7x7 s2 p3, 3 -> 64, then IN + ReLU (architecture.md §2.2)."""

    def __init__(self):
        super().__init__()
        self.conv = nn.Conv2d(3, 64, kernel_size=7, stride=2, padding=3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(instance_norm(self.conv(x)))


class Encoder(nn.Module):
    """BasicEncoderQuarter + iAFF: (B,3,H,W) -> (B,256,H/4,W/4) (architecture.md §2.2).

    Backbone convs use kaiming_normal_(fan_out, relu) weights; iAFF convs keep PyTorch defaults.
    """

    def __init__(self, use_aff: bool = True):
        super().__init__()
        self.stem = Stem()
        self.layer1 = nn.Sequential(ResBlock(64, 64, 1, use_aff), ResBlock(64, 64, 1, use_aff))
        self.layer2 = nn.Sequential(ResBlock(64, 96, 2, use_aff), ResBlock(96, 96, 1, use_aff))
        self.layer3 = nn.Sequential(ResBlock(96, 128, 1, use_aff), ResBlock(128, 128, 1, use_aff))
        self.out = nn.Conv2d(128, FEATURE_DIM, kernel_size=1)
        convs = [self.stem.conv, self.out]
        for layer in (self.layer1, self.layer2, self.layer3):
            for block in layer:
                convs.extend(block.backbone_convs())
        for conv in convs:
            nn.init.kaiming_normal_(conv.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x)
        x = self.layer3(self.layer2(self.layer1(x)))
        return self.out(x)


# ------------------------------------------------------------------------------------------------
# Update blocks (architecture.md §2.7)
# ------------------------------------------------------------------------------------------------


def conv(cin: int, cout: int, k, padding) -> nn.Conv2d:
    """Conv2d with bias and PyTorch default init (update blocks, architecture.md §2.2/§2.7)."""
    return nn.Conv2d(cin, cout, kernel_size=k, padding=padding)


class SmallMotionEncoder(nn.Module):
    """U_IP motion encoder (DIP SmallMotionEncoder): corr 10 ch + flow 2 ch -> 96 ch (architecture.md §2.7)."""

    def __init__(self, corr_channels: int):
        super().__init__()
        self.corr1 = conv(corr_channels, 96, 1, 0)
        self.flow1 = conv(2, 64, 5, 2)
        self.flow2 = conv(64, 32, 3, 1)
        self.out = conv(128, 94, 3, 1)

    def forward(self, flow: torch.Tensor, corr: torch.Tensor) -> torch.Tensor:
        a = F.relu(self.corr1(corr))
        b = F.relu(self.flow2(F.relu(self.flow1(flow))))
        m = F.relu(self.out(torch.cat([a, b], dim=1)))
        return torch.cat([m, flow], dim=1)


class BasicMotionEncoder(nn.Module):
    """U_RLS motion encoder (DIP BasicMotionEncoder): corr 21 ch + flow 2 ch -> 128 ch (architecture.md §2.7)."""

    def __init__(self, corr_channels: int):
        super().__init__()
        self.corr1 = conv(corr_channels, 64, 1, 0)
        self.corr2 = conv(64, 128, 3, 1)
        self.flow1 = conv(2, 64, 5, 2)
        self.flow2 = conv(64, 64, 3, 1)
        self.out = conv(192, 126, 3, 1)

    def forward(self, flow: torch.Tensor, corr: torch.Tensor) -> torch.Tensor:
        a = F.relu(self.corr2(F.relu(self.corr1(corr))))
        b = F.relu(self.flow2(F.relu(self.flow1(flow))))
        m = F.relu(self.out(torch.cat([a, b], dim=1)))
        return torch.cat([m, flow], dim=1)


class ConvGRU(nn.Module):
    """3x3 ConvGRU (architecture.md §2.7, paper section 3.2.2)."""

    def __init__(self, hidden: int, inp: int):
        super().__init__()
        self.convz = conv(hidden + inp, hidden, 3, 1)
        self.convr = conv(hidden + inp, hidden, 3, 1)
        self.convq = conv(hidden + inp, hidden, 3, 1)

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        hx = torch.cat([h, x], dim=1)
        z = torch.sigmoid(self.convz(hx))
        r = torch.sigmoid(self.convr(hx))
        q = torch.tanh(self.convq(torch.cat([r * h, x], dim=1)))
        return (1 - z) * h + z * q


class SepConvGRU(nn.Module):
    """Separable ConvGRU: horizontal (1,5) pass then vertical (5,1) pass (architecture.md §2.7, DIP/RAFT)."""

    def __init__(self, hidden: int, inp: int):
        super().__init__()
        self.convz_h = conv(hidden + inp, hidden, (1, 5), (0, 2))
        self.convr_h = conv(hidden + inp, hidden, (1, 5), (0, 2))
        self.convq_h = conv(hidden + inp, hidden, (1, 5), (0, 2))
        self.convz_v = conv(hidden + inp, hidden, (5, 1), (2, 0))
        self.convr_v = conv(hidden + inp, hidden, (5, 1), (2, 0))
        self.convq_v = conv(hidden + inp, hidden, (5, 1), (2, 0))

    @staticmethod
    def _pass(h, x, convz, convr, convq):
        hx = torch.cat([h, x], dim=1)
        z = torch.sigmoid(convz(hx))
        r = torch.sigmoid(convr(hx))
        q = torch.tanh(convq(torch.cat([r * h, x], dim=1)))
        return (1 - z) * h + z * q

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        h = self._pass(h, x, self.convz_h, self.convr_h, self.convq_h)
        return self._pass(h, x, self.convz_v, self.convr_v, self.convq_v)


class DispHead(nn.Module):
    """Delta = conv2(ReLU(conv1(h))), 2 output channels (Delta_x, Delta_y) (architecture.md §2.7)."""

    def __init__(self, hidden: int, mid: int):
        super().__init__()
        self.conv1 = conv(hidden, mid, 3, 1)
        self.conv2 = conv(mid, 2, 3, 1)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return self.conv2(F.relu(self.conv1(h)))


class MaskHead(nn.Module):
    """Convex-upsampling mask M = 0.25 * conv2(ReLU(conv1(h))), 144 channels (architecture.md §2.7)."""

    def __init__(self, hidden: int):
        super().__init__()
        self.conv1 = conv(hidden, 256, 3, 1)
        self.conv2 = conv(256, 9 * UPSAMPLE_RATE * UPSAMPLE_RATE, 1, 0)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return 0.25 * self.conv2(F.relu(self.conv1(h)))


class UpdateBlock(nn.Module):
    """One update block: motion encoder, GRU on x = cat[c, motion], disparity head, mask head (architecture.md §2.7)."""

    def forward(self, h, c, corr, flow):
        motion = self.motion(flow, corr)
        h = self.gru(h, torch.cat([c, motion], dim=1))
        return h, self.mask_head(h), self.disp_head(h)


class IPUpdateBlock(UpdateBlock):
    """U_IP = DIP SmallUpdateBlock: ConvGRU 3x3, head 128 -> 128 -> 2 (architecture.md §2.7)."""

    def __init__(self, corr_channels: int = IP_GROUPS * len(IP_SEED_OFFSETS)):
        super().__init__()
        self.motion = SmallMotionEncoder(corr_channels)
        self.gru = ConvGRU(HIDDEN_DIM, CONTEXT_DIM + 96)
        self.disp_head = DispHead(HIDDEN_DIM, 128)
        self.mask_head = MaskHead(HIDDEN_DIM)


class RLSUpdateBlock(UpdateBlock):
    """U_RLS = DIP BasicUpdateBlock: SepConvGRU, head 128 -> 256 -> 2 (architecture.md §2.7)."""

    def __init__(self, corr_channels: int):
        super().__init__()
        self.motion = BasicMotionEncoder(corr_channels)
        self.gru = SepConvGRU(HIDDEN_DIM, CONTEXT_DIM + 128)
        self.disp_head = DispHead(HIDDEN_DIM, 256)
        self.mask_head = MaskHead(HIDDEN_DIM)


# ------------------------------------------------------------------------------------------------
# Full network (architecture.md §1, §2.9)
# ------------------------------------------------------------------------------------------------

Iters = Union[int, Tuple[int, int], Sequence[int]]


class MIPNetTorch(nn.Module):
    """MIPNet: encoder + IP/RLS update blocks shared by the 1/16 and 1/4 levels (architecture.md §1-§2.9, §2.10).

    forward(left, right, iters=(6, 6), seed=20, disp_init=None):
      left, right: (N,3,H,W) in 0..255, H and W multiples of 16 (no padding is done here).
      disp_init: optional (N,1,H/16,W/16) positive disparity in 1/16-level pixels.
      Training mode: list of all predictions (N,1,H,W); eval mode: the final prediction only.
    """

    def __init__(
        self,
        use_aff: bool = True,
        use_ip: bool = True,
        use_rls: bool = True,
        rx: int = 3,
        ry: int = 1,
        vertical_constraint: bool = True,
        gamma_shape: float = 2.0,
        gamma_scale: float = 16.0,
        max_disp_init: float = 192.0,
    ):
        super().__init__()
        if not (use_ip or use_rls):
            raise ValueError("at least one of use_ip / use_rls must be enabled")
        self.use_aff = use_aff
        self.use_ip = use_ip
        self.use_rls = use_rls
        self.rx = rx
        self.ry = ry
        self.vertical_constraint = vertical_constraint
        self.gamma_shape = gamma_shape
        self.gamma_scale = gamma_scale
        self.max_disp_init = max_disp_init
        self.encoder = Encoder(use_aff)
        self.update_ip = IPUpdateBlock() if use_ip else None
        self.update_rls = RLSUpdateBlock((2 * rx + 1) * (2 * ry + 1)) if use_rls else None

    def freeze_bn(self) -> None:
        """Put every BatchNorm2d in eval mode (use running statistics), RAFT habit."""
        for m in self.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eval()

    @staticmethod
    def _parse_iters(iters: Iters) -> Tuple[int, int]:
        """iters int -> same count at both levels, or (n16, n4) (architecture.md §2.8)."""
        if isinstance(iters, int):
            n16, n4 = iters, iters
        else:
            n16, n4 = (int(v) for v in iters)
        if n16 < 1 or n4 < 0:
            raise ValueError(f"iters must give n16 >= 1 and n4 >= 0, got {iters!r}")
        return n16, n4

    def _initial_flow(self, n, h16, w16, seed, disp_init, dtype, device) -> torch.Tensor:
        """1/16 flow field (N,2,h16,w16): f_x = -d0/16 from the gamma draw, or -disp_init; f_y = 0 (architecture.md §2.4)."""
        if disp_init is not None:
            if tuple(disp_init.shape) != (n, 1, h16, w16):
                raise ValueError(
                    f"disp_init must have shape {(n, 1, h16, w16)}, got {tuple(disp_init.shape)}"
                )
            fx = -disp_init.detach().to(dtype=dtype, device=device)
        else:
            shape = (n, 1, h16, w16)
            if self.training or seed is None:
                d0 = gamma_disp_init(shape, self.gamma_shape, self.gamma_scale, self.max_disp_init)
            else:
                gen = torch.Generator(device="cpu")
                gen.manual_seed(int(seed))
                d0 = gamma_disp_init(
                    shape, self.gamma_shape, self.gamma_scale, self.max_disp_init, gen, int(seed)
                )
            fx = -(d0 / 16).to(dtype=dtype, device=device)
        return torch.cat([fx, torch.zeros_like(fx)], dim=1)

    def _blocks(self, fl: torch.Tensor, fr: torch.Tensor):
        """(update block, correlation function of the detached flow) pairs for one level, IP first."""
        blocks = []
        if self.use_ip:
            stack = build_ip_stack(fr)
            blocks.append((self.update_ip, lambda f: ip_correlation(fl, warp(stack, f))))
        if self.use_rls:
            blocks.append((self.update_rls, lambda f: rls_correlation(fl, warp(fr, f), self.rx, self.ry)))
        return blocks

    def _run_level(
        self,
        fl: torch.Tensor,
        fr: torch.Tensor,
        h: torch.Tensor,
        c: torch.Tensor,
        flow: torch.Tensor,
        n_iters: int,
        to_full: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
        preds: List[torch.Tensor],
    ) -> Tuple[torch.Tensor, torch.Tensor]:
        """n_iters iterations of [IP + GRU_IP] then [RLS + GRU_RLS] at one level (architecture.md §2.9).

        Appends the full-resolution prediction of every sub-update to `preds` in training mode.
        Returns the final flow and the mask of the last sub-update.
        """
        mask = None
        blocks = self._blocks(fl, fr)
        for _ in range(n_iters):
            for block, correlate in blocks:
                flow = flow.detach()
                corr = correlate(flow)
                h, mask, delta = block(h, c, corr, flow)
                if self.vertical_constraint:
                    delta = torch.cat([delta[:, :1], torch.zeros_like(delta[:, 1:])], dim=1)
                flow = flow + delta
                if self.training:
                    preds.append(to_full(flow, mask))
        return flow, mask

    def forward(
        self,
        left: torch.Tensor,
        right: torch.Tensor,
        iters: Iters = (6, 6),
        seed: Optional[int] = 20,
        disp_init: Optional[torch.Tensor] = None,
    ) -> Union[torch.Tensor, List[torch.Tensor]]:
        """Forward pass, architecture.md §1 data flow and §2.9 schedule."""
        n16, n4 = self._parse_iters(iters)
        n, _, height, width = left.shape
        if height % 16 or width % 16:
            raise ValueError(f"H and W must be multiples of 16, got {height}x{width}")
        dtype = self.encoder.out.weight.dtype
        device = self.encoder.out.weight.device

        # a.1 / a.2: normalise, one encoder pass over cat[L, R], features in the model dtype.
        images = torch.cat([left, right], dim=0).to(dtype=dtype, device=device)
        images = 2 * (images / 255) - 1
        fmap = self.encoder(images).to(dtype)
        fl4, fr4 = torch.split(fmap, [n, n], dim=0)

        # a.3: context split and 4x4 average-pooled 1/16 level.
        h4_0 = torch.tanh(fl4[:, :HIDDEN_DIM])
        c4 = F.relu(fl4[:, HIDDEN_DIM:])
        fl16 = F.avg_pool2d(fl4, kernel_size=4, stride=4)
        fr16 = F.avg_pool2d(fr4, kernel_size=4, stride=4)
        h16_0 = F.avg_pool2d(h4_0, kernel_size=4, stride=4)
        c16 = F.avg_pool2d(c4, kernel_size=4, stride=4)

        flow16 = self._initial_flow(n, height // 16, width // 16, seed, disp_init, dtype, device)
        preds: List[torch.Tensor] = []

        def full_from_16(f, m):
            return -bilinear_up4(convex_upsample(f, m))[:, :1]

        def full_from_4(f, m):
            return -convex_upsample(f, m)[:, :1]

        flow16, mask16 = self._run_level(fl16, fr16, h16_0, c16, flow16, n16, full_from_16, preds)
        # Hand-over: convex x4 with the mask of the last 1/16 sub-update; fresh hidden state h4_0.
        flow4 = convex_upsample(flow16, mask16)
        if n4 == 0:
            return preds if self.training else -bilinear_up4(flow4)[:, :1]
        flow4, mask4 = self._run_level(fl4, fr4, h4_0, c4, flow4, n4, full_from_4, preds)
        return preds if self.training else full_from_4(flow4, mask4)


# ------------------------------------------------------------------------------------------------
# Loss (architecture.md §3.1)
# ------------------------------------------------------------------------------------------------


def sequence_loss_torch(
    preds: Union[torch.Tensor, Sequence[torch.Tensor]],
    gt: torch.Tensor,
    valid: torch.Tensor,
    gamma: float = 0.8,
    max_disp: float = 700.0,
) -> torch.Tensor:
    """L = sum_i gamma^(n-1-i) * mean_{valid} |d_i - d_gt| (architecture.md §3.1).

    valid = (valid >= 0.5) AND finite gt AND |gt| < max_disp; invalid gt is zeroed before the
    subtraction; a prediction with no valid pixel contributes 0. gt/valid: (N,1,H,W) or (N,H,W).
    """
    if isinstance(preds, torch.Tensor):
        preds = [preds]
    if gt.dim() == 3:
        gt = gt.unsqueeze(1)
    if valid.dim() == 3:
        valid = valid.unsqueeze(1)
    mask = valid if valid.dtype == torch.bool else valid >= 0.5
    mask = mask & torch.isfinite(gt) & (gt.abs() < max_disp)
    gt = torch.where(mask, gt, torch.zeros_like(gt))
    count = mask.sum()
    n = len(preds)
    loss = preds[0].new_zeros(())
    for i, pred in enumerate(preds):
        err = torch.where(mask, (pred - gt).abs(), torch.zeros_like(pred))
        loss = loss + gamma ** (n - 1 - i) * err.sum() / count.clamp(min=1)
    return loss
