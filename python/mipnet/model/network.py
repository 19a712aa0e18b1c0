"""``MIPNet``: the Multilevel Inverse Patchmatch Network (Leng et al., JMSE 2023) on mipnet's engine.

Layer by layer as docs/architecture.md §2 describes it (the paper's network, with the choices the paper leaves
open made explicit there). Flow fields are carried as numpy-backed tensors in level pixel units with
f = (f_x, f_y), f_x = -disparity, f_y = 0 (vertical constraint).
"""

from __future__ import annotations

import json
from typing import Any, Sequence

import numpy as np
from PIL import Image

from .. import ops
from ..autograd import checkpoint, is_grad_enabled, no_grad
from ..profiler import scope
from .blocks import Encoder, UpdateBlock, ip_update_block, rls_update_block
from ..errors import ArgumentError, FormatError, ShapeError
from .memory import check_forward, recompute_heads
from ..nn import BatchNorm2d, Module
from ..random import default_generator
from ..serialization import load_safetensors, save_safetensors
from ..tensor import Tensor
from . import pretrained
from .config import DIVISOR, MIN_SIZE, MIPNetConfig
from .state import NetworkState

__all__ = ["MIPNet", "MIPNetConfig", "load", "gamma_draw"]


class MIPNet(Module):
    """MIPNet stereo network. ``model(left, right)`` returns positive left-view disparity.

    Args:
        use_aff, use_ip, use_rls, rx, ry, vertical_constraint, gamma_shape, gamma_scale,
        max_disp_init: see :class:`MIPNetConfig`.

    Call: ``forward(left, right, iters=(6, 6), seed=20, disp_init=None, scale=1.0)``;
    ``forward_with_state`` also returns the state the pass ends in and can start from one (video, docs/video.md).

    Inputs: HxWx3 uint8 RGB arrays, HxW grayscale arrays, or (N,3,H,W) float arrays / Tensors in
    0..255; any H, W >= 32 (replicate-padded to a multiple of 16 and cropped back).
    Eval mode returns a numpy array (H,W) (or (N,H,W) for batched input) of the model's dtype;
    training mode returns the list of supervised predictions, each an (N,1,H,W) Tensor.

    ``scale`` (eval mode only) resizes both images by that factor before the network runs (an
    antialiased bilinear resize) and the disparity back to the input size, its values divided by the
    horizontal factor actually applied: ``scale=0.5`` on a large photograph whose disparities exceed
    what the network was trained on (the shipped weights: up to about 160 px) runs at a quarter of
    the pixels, as FoundationStereo's ``--scale``. ``disp_init`` is then at 1/16 of the resized size.
    """

    def __init__(self, *, use_aff: bool = True, use_ip: bool = True, use_rls: bool = True, rx: int = 3, ry: int = 1,
                 vertical_constraint: bool = True, gamma_shape: float = 2.0, gamma_scale: float = 16.0,
                 max_disp_init: float = 192.0):
        """A MIPNet with freshly initialised weights (trained ones: :meth:`MIPNet.pretrained`, :func:`mipnet.load`).

        The keywords are the fields of :class:`MIPNetConfig`, with its defaults (the full model of the paper);
        ``MIPNet(**json.loads(config.to_json()))`` rebuilds a saved architecture.

        Parameters
        ----------
        use_aff : bool, default True
            Fuse each encoder residual block's branches with iAFF (iterative attentional feature fusion)
            instead of a plain sum (the paper's Table 1 ablation).
        use_ip : bool, default True
            Run the Inverse-PatchMatch sub-update (IP: correlation at the flow and four diagonal seeds) in
            every iteration.
        use_rls : bool, default True
            Run the Row Local Search sub-update (RLS: correlation over a window of shifts around the flow)
            in every iteration, after IP. At least one of ``use_ip`` and ``use_rls`` must be on.
        rx, ry : int, default 3, 1
            Half-width and half-height of the RLS search window, in level pixels: it correlates
            (2 rx + 1) x (2 ry + 1) shifts. Non-negative.
        vertical_constraint : bool, default True
            Keep the flow's vertical component at zero (rectified pairs: disparity moves along rows only);
            False lets the updates move it vertically too.
        gamma_shape, gamma_scale : float, default 2.0, 16.0
            Shape k and scale theta of the Gamma distribution the initial disparity is drawn from, per 1/16
            pixel, in full-resolution pixels (mean k * theta = 32 by default). Positive.
        max_disp_init : float, default 192.0
            The initial draws are clipped to [0, max_disp_init] pixels. Positive.

        Raises
        ------
        ArgumentError
            Neither IP nor RLS on, a negative ``rx`` / ``ry``, or a non-positive Gamma parameter.
        TypeError
            A positional argument or an unknown keyword.
        """
        super().__init__()
        self.config = MIPNetConfig(use_aff=use_aff, use_ip=use_ip, use_rls=use_rls, rx=rx, ry=ry,
                                   vertical_constraint=vertical_constraint, gamma_shape=gamma_shape,
                                   gamma_scale=gamma_scale, max_disp_init=max_disp_init)
        cfg = self.config
        self.encoder = Encoder(use_aff=cfg.use_aff)
        if cfg.use_ip:
            self.update_ip = ip_update_block()
        if cfg.use_rls:
            self.update_rls = rls_update_block((2 * cfg.rx + 1) * (2 * cfg.ry + 1))
        self._bn_frozen = False

    # ---- modes ---------------------------------------------------------------------------------------
    def train(self, mode: bool = True) -> "MIPNet":
        super().train(mode)
        if self._bn_frozen:
            self.freeze_bn()
        return self

    def freeze_bn(self) -> "MIPNet":
        """Keeps every BatchNorm in eval mode (running statistics), also after ``train()`` (RAFT habit)."""
        self._bn_frozen = True
        for m in self.modules():
            if isinstance(m, BatchNorm2d):
                object.__setattr__(m, "training", False)
        return self

    def unfreeze_bn(self) -> "MIPNet":
        self._bn_frozen = False
        return self.train(self.training)

    @property
    def dtype(self) -> np.dtype:
        return self.encoder.stem.conv.weight.dtype

    def _blocks(self) -> list[tuple[str, UpdateBlock]]:
        """The sub-updates of one iteration, in order: IP then RLS (architecture.md §2.7)."""
        return [(name, getattr(self, "update_" + name)) for name, on in
                (("ip", self.config.use_ip), ("rls", self.config.use_rls)) if on]

    # ---- the forward pass ----------------------------------------------------------------------------
    def forward(self, left: Any, right: Any, iters: int | Sequence[int] = (6, 6), seed: int | None = 20,
                disp_init: Any = None, scale: float = 1.0):
        """Left-view disparity of a rectified stereo pair (call the model: ``model(left, right)``).

        Parameters
        ----------
        left, right : array_like or Tensor
            The rectified pair, 0..255: H x W x 3 RGB (uint8 or float), H x W or H x W x 1 grayscale
            (repeated to three channels), or a batch (N, 3, H, W) as a float array or Tensor. Both of one
            shape, H and W at least 32 (replicate-padded to multiples of 16 inside, cropped back); finite.
            Converted to the model's dtype.
        iters : int or (int, int), default (6, 6)
            IPM iterations (n16, n4) at the 1/16 and the 1/4 level; an int runs as many at both.
            ``n16 >= 1``, ``n4 >= 0`` (0: stop at 1/16 and upsample its hand-over field).
        seed : int or None, default 20
            Eval mode: seeds the Gamma draw of the initial disparity, so a pair always gives the same
            result; None draws from mipnet's global generator (``mipnet.manual_seed``), as training mode
            always does.
        disp_init : array_like or Tensor, optional
            The initial disparity instead of the Gamma draw, (N, 1, H16, W16) in full-resolution pixels,
            H16, W16 = the padded (and, with ``scale``, resized) size / 16; finite.
        scale : float, default 1.0
            Eval mode only: run the network on both images resized by this factor (antialiased bilinear)
            and resize the disparity back, its values divided by the horizontal factor applied. Below 1
            for photographs whose disparities exceed the trained range (about 160 px for the shipped
            weights); the resized images must stay at least 32 x 32.

        Returns
        -------
        numpy.ndarray or list of Tensor
            Eval mode: the final disparity (positive, pixels of the input) as a numpy array of the
            model's dtype, (H, W) for a single pair or (N, H, W) for a batch. Training mode: every
            supervised prediction in order, n16 * s at the 1/16 level then n4 * s at 1/4 (s = 1 or 2
            sub-updates per iteration: IP and/or RLS), each an (N, 1, H, W) Tensor for the sequence loss.

        Raises
        ------
        ShapeError
            An image of another layout, smaller than 32 x 32 (also after ``scale``), the two images of
            different shapes, or ``disp_init`` of the wrong shape.
        ArgumentError
            Bad ``iters``, an image of a non-numeric dtype or with NaN / inf, a non-finite ``disp_init``,
            a non-positive ``scale``, or ``scale`` in training mode.
        MemoryLimitError
            The pass needs more memory than the process may still use (:func:`mipnet.model.memory.check`;
            ``MIPNET_MEMORY_CHECK=0`` skips the check).
        """
        l, r, batched, size, pad, (n16, n4) = self._prepare(left, right, iters, scale)
        if self.training:
            preds, _ = self._run(l, r, pad, n16, n4, seed, disp_init)
            return [_crop(p, pad, l.shape) for p in preds]
        disp, _ = self._evaluate(l, r, size, pad, (n16, n4), seed, disp_init, None)
        return disp if batched else disp[0]

    def forward_with_state(self, left: Any, right: Any, iters: int | Sequence[int] = (6, 6), seed: int | None = 20,
                           init: NetworkState | None = None, scale: float = 1.0) -> tuple[np.ndarray, NetworkState]:
        """Eval mode: the disparity of :meth:`forward` and the state the pass ends in, optionally starting from one.

        With ``init=None`` the disparity is exactly ``forward(left, right, iters, seed, scale=scale)``'s. Each piece of
        ``init`` that is set replaces its cold start (:class:`mipnet.model.state.NetworkState`: the 1/16 field instead
        of the gamma draw, the hand-over field, either level's hidden state); :class:`mipnet.Stream` passes the state
        of the previous video frame this way (docs/video.md).

        Parameters
        ----------
        left, right, iters, seed, scale
            As :meth:`forward`.
        init : NetworkState, optional
            The pieces to start from, shaped for this batch and the padded (and, with ``scale``, resized) size.

        Returns
        -------
        disparity : numpy.ndarray
            As :meth:`forward` in eval mode: (H, W), or (N, H, W) for a batch.
        state : NetworkState
            Both levels' fields and hidden states after their iterations (``flow4``, ``hidden4`` None when
            ``n4 = 0``).

        Raises
        ------
        ArgumentError
            Training mode; or as :meth:`forward`; or ``init`` holds NaN or inf.
        ShapeError
            As :meth:`forward`, or a piece of ``init`` of the wrong shape.
        MemoryLimitError
            As :meth:`forward`.
        """
        if self.training:
            raise ArgumentError("MIPNet.forward_with_state runs in eval mode only (call model.eval() first)")
        l, r, batched, size, pad, n_iters = self._prepare(left, right, iters, scale)
        disp, final = self._evaluate(l, r, size, pad, n_iters, seed, None, init)
        # the final tensors become arrays only here, where a caller asked for the state
        state = NetworkState(**{name: t.numpy() for name, t in final.items()})
        return (disp if batched else disp[0]), state

    def _prepare(self, left: Any, right: Any, iters: int | Sequence[int], scale: float):
        """The checked batch (N,3,H,W) of each image (resized with ``scale``), whether the input was batched, the
        input size (H, W), the padding and (n16, n4); MemoryLimitError before a pass that would not fit."""
        n16, n4 = _parse_iters(iters)
        l, batched = _as_batch(left, "left", self.dtype)
        r, _ = _as_batch(right, "right", self.dtype)
        if l.shape != r.shape:
            raise ShapeError(f"MIPNet: left and right images differ in shape: left={list(l.shape)}, right={list(r.shape)}")
        size = l.shape[2:]
        if scale != 1.0:
            if self.training:
                raise ArgumentError("MIPNet: scale is for eval mode; resize training pairs with their disparity instead")
            l, r = (_resize_images(a, _scaled_size(size, scale)) for a in (l, r))
        pad = _padding(l.shape[2], l.shape[3])
        check_forward(self, l.shape, (n16, n4), self.training and is_grad_enabled())  # MemoryLimitError before OOM
        return l, r, batched, size, pad, (n16, n4)

    def _evaluate(self, l: np.ndarray, r: np.ndarray, size: tuple[int, int], pad: tuple[int, int, int, int],
                  iters: tuple[int, int], seed: int | None, disp_init: Any,
                  init: NetworkState | None) -> tuple[np.ndarray, dict[str, Tensor]]:
        """The eval pass: the disparity (N, H, W) at the input size ``size`` and the final state's tensors."""
        with no_grad():
            preds, final = self._run(l, r, pad, *iters, seed, disp_init, init)
            pred = _crop(preds[-1], pad, l.shape)
            if pred.shape[2:] != size:
                # back to the input size; disparity in input pixels = resized disparity · W / W_resized
                pred = ops.interpolate(pred, size=tuple(size), mode="bilinear", align_corners=False) * (size[1] / l.shape[3])
            disp = pred.numpy()[:, 0]
        return disp, final

    def _run(self, left: np.ndarray, right: np.ndarray, pad: tuple[int, int, int, int], n16: int, n4: int,
             seed: int | None, disp_init: Any,
             init: NetworkState | None = None) -> tuple[list[Tensor], dict[str, Tensor]]:
        """The predictions (all of them in training, the last one in eval) and the tensors of the state the pass
        ends in (the fields of :class:`NetworkState`, uncopied), starting from the pieces of ``init`` that are set
        (architecture.md §2.9)."""
        n = left.shape[0]
        # padded size: the input plus the [left, right, top, bottom] padding
        padded = (left.shape[2] + pad[2] + pad[3], left.shape[3] + pad[0] + pad[1])
        init = self._checked_init(init, n, padded)
        # normalise to [-1, 1] as architecture.md §1 writes it, I' = 2 (I / 255) - 1; replicate-pad both images identically
        with scope("encoder"):
            images = ops.pad(Tensor(2 * (np.concatenate([left, right]) / 255) - 1), list(pad), mode="replicate")
            fl4, fr4 = ops.split(self.encoder(images), [n, n], 0)
            hidden4 = ops.tanh(fl4[:, :128])
            context4 = ops.relu(fl4[:, 128:])
            fl16, fr16, hidden16, context16 = (ops.avg_pool2d(t, 4, 4) for t in (fl4, fr4, hidden4, context4))
        if init.flow16 is not None:
            flow16 = Tensor(init.flow16)
        else:
            flow16 = self._initial_flow(n, fl16.shape[2], fl16.shape[3], seed, disp_init)
        if init.hidden16 is not None:
            hidden16 = Tensor(init.hidden16)
        collect = self.training

        preds: list[Tensor] = []
        with scope("level 1/16"):
            flow, mask, hidden16 = self._iterate(fl16, fr16, hidden16, context16, flow16, n16,
                                                 preds if collect else None, 4)
        if n4 == 0:
            # eval: the hand-over field, convex x4 then bilinear x4 (architecture.md §2.8); training has its 1/16 predictions
            return (preds if collect else [self._prediction(flow, mask, 4)]), {"flow16": flow, "hidden16": hidden16}
        if init.flow4 is not None:
            flow4 = Tensor(init.flow4)
        else:
            with no_grad():  # the hand-over field is detached (architecture.md §2.9)
                flow4 = ops.convex_upsample(flow.detach(), mask.detach(), rate=4)
        if init.hidden4 is not None:
            hidden4 = Tensor(init.hidden4)
        with scope("level 1/4"):
            flow4, _, hidden4 = self._iterate(fl4, fr4, hidden4, context4, flow4, n4, preds, 1 if collect else None)
        return preds, {"flow16": flow, "hidden16": hidden16, "flow4": flow4, "hidden4": hidden4}

    def _checked_init(self, init: NetworkState | None, n: int, padded: tuple[int, int]) -> NetworkState:
        """``init`` checked against a batch of ``n`` padded images and cast to the model's dtype; an empty
        state for None."""
        if init is None:
            return NetworkState()
        if not isinstance(init, NetworkState):
            raise ArgumentError(f"MIPNet: init must be a NetworkState, got {type(init).__name__}")
        init.check(n, padded)
        return init.as_dtype(self.dtype)

    def _iterate(self, fl: Tensor, fr: Tensor, hidden: Tensor, context: Tensor, flow: Tensor, iters: int,
                 preds: list[Tensor] | None, bilinear: int | None) -> tuple[Tensor, Tensor, Tensor]:
        """``iters`` IPM iterations at one level. Appends a prediction after every sub-update when
        ``bilinear`` is set (4: 1/16 level, convex x4 then bilinear x4; 1: 1/4 level), else only the
        final one (eval at the 1/4 level) or none (eval at 1/16). Returns the last flow, mask and hidden
        state; the mask head runs only where its mask is used."""
        operands = _CorrelationOperands(fl, fr, self.config)
        blocks = self._blocks()
        every = preds is not None and bilinear is not None
        # training at large sizes: each prediction's mask head and upsampling are recomputed in the
        # backward rather than kept (memory.HEAD_CHANNELS maps of the level per sub-update)
        recompute = every and is_grad_enabled() and recompute_heads(
            fl.shape[0] * fl.shape[2] * fl.shape[3], iters * len(blocks), fl.data.itemsize)
        mask = None
        for t in range(iters):
            for b, (name, block) in enumerate(blocks):
                flow = flow.detach()
                corr = operands.correlation(name, flow)
                last = t == iters - 1 and b == len(blocks) - 1
                hidden, mask, delta = block(hidden, context, corr, flow, with_mask=(every or last) and not recompute)
                flow = flow + (_vertical_constraint(delta) if self.config.vertical_constraint else delta)
                if recompute:
                    preds.append(checkpoint(lambda h, f, m=block.mask_head: self._prediction(f, m(h), bilinear), hidden, flow))
                    if last:
                        with no_grad():  # the hand-over mask (detached, architecture.md §2.9)
                            mask = block.mask_head(hidden)
                elif preds is not None and (bilinear is not None or last):
                    preds.append(self._prediction(flow, mask, bilinear or 1))
        return flow, mask, hidden

    @staticmethod
    def _prediction(flow: Tensor, mask: Tensor | None, bilinear: int) -> Tensor:
        """Full-resolution positive disparity -f_x from a level's flow (a.9)."""
        fx = flow[:, 0:1]
        up = fx if mask is None else ops.convex_upsample(fx, mask, rate=4)
        if bilinear > 1:
            h, w = up.shape[2], up.shape[3]
            up = ops.interpolate(up, size=(h * bilinear, w * bilinear), mode="bilinear", align_corners=True) * float(bilinear)
        return -up

    def _initial_flow(self, n: int, h16: int, w16: int, seed: int | None, disp_init: Any) -> Tensor:
        """The 1/16 flow (N,2,h16,w16): f_x = -d0 with d0 the gamma draw (architecture.md §2.4) or ``disp_init``."""
        dtype = self.dtype
        if disp_init is not None:
            d0 = np.asarray(disp_init.numpy() if isinstance(disp_init, Tensor) else disp_init, dtype=np.float64)
            if d0.shape != (n, 1, h16, w16):
                raise ShapeError(f"MIPNet: disp_init must have shape {[n, 1, h16, w16]} (N,1,H/16,W/16 of the padded "
                                 f"input), got {list(d0.shape)}")
            if not np.all(np.isfinite(d0)):
                raise ArgumentError("MIPNet: disp_init contains NaN or inf")
        elif self.training or seed is None:
            d0 = gamma_draw(default_generator(), (n, 1, h16, w16), self.config.gamma_shape, self.config.gamma_scale,
                            self.config.max_disp_init) / 16.0
        else:
            # eval with a seed: every pair of a batch starts from the draw its own run would make, so a pair's
            # disparity does not depend on the batch it comes in
            d0 = gamma_draw(np.random.default_rng(seed), (1, 1, h16, w16), self.config.gamma_shape,
                            self.config.gamma_scale, self.config.max_disp_init) / 16.0
            d0 = np.repeat(d0, n, axis=0)
        return Tensor(np.concatenate([-d0, np.zeros_like(d0)], axis=1).astype(dtype))

    # ---- weights ---------------------------------------------------------------------------------------
    @classmethod
    def pretrained(cls) -> "MIPNet":
        """The eval-mode model with the weights shipped inside the package (``mipnet info`` says what
        they were trained on; ``docs/training.md`` how)."""
        if not pretrained.available():
            raise FormatError(f"mipnet ships no trained weights in this installation (expected {pretrained.PRETRAINED_PATH})")
        return load(str(pretrained.PRETRAINED_PATH)).eval()

    def save(self, path: str, **metadata: str) -> None:
        """Writes the state dict to a safetensors file with the config in its metadata (atomic)."""
        meta = {"format": "mipnet", "config": self.config.to_json(), **{k: str(v) for k, v in metadata.items()}}
        save_safetensors(path, self.state_dict(), meta)


def load(path: str, strict: bool = True) -> MIPNet:
    """A ``MIPNet`` built from the config stored in a safetensors file written by ``MIPNet.save``,
    with its weights loaded. A file that is not such weights raises ``FormatError`` naming it."""
    tensors, meta = load_safetensors(path)
    try:
        config = json.loads(meta["config"]) if "config" in meta else {}
        if not isinstance(config, dict):
            raise TypeError(f"the config is a JSON {type(config).__name__}, not an object")
        model = MIPNet(**config)
        model.load_state_dict(tensors, strict=strict)
    except (ValueError, TypeError, RuntimeError) as e:  # bad JSON, unknown or bad config keys, missing/odd weights
        message = " ".join(str(e).split())
        raise FormatError(f"{path}: not MIPNet weights ({message[:300]}{'...' if len(message) > 300 else ''})") from None
    return model


def gamma_draw(rng: np.random.Generator, shape: tuple[int, ...], k: float, theta: float, max_disp: float) -> np.ndarray:
    """d0 ~ Gamma(k, theta) clamped to [0, max_disp] (architecture.md §2.4): for integer k,
    d0 = -theta * Σ_{j=1..k} ln U_j with U_j = 1 - uniform[0,1) in (0, 1]."""
    if float(k).is_integer():
        u = 1.0 - rng.random((int(k),) + tuple(shape))
        d0 = -theta * np.log(u).sum(axis=0)
    else:
        d0 = rng.gamma(k, theta, size=shape)
    return np.clip(d0, 0.0, max_disp)


def _parse_iters(iters: int | Sequence[int]) -> tuple[int, int]:
    n16, n4 = (iters, iters) if isinstance(iters, (int, np.integer)) else tuple(iters)
    if n16 < 1 or n4 < 0:
        raise ArgumentError(f"MIPNet: iters=(n16, n4) needs n16 >= 1 and n4 >= 0, got {iters}")
    return int(n16), int(n4)


def _as_batch(img: Any, name: str, dtype: np.dtype) -> tuple[np.ndarray, bool]:
    """(N,3,H,W) array in 0..255 of ``dtype`` from HxWx3 / HxW / HxWx1 / (N,3,H,W) input; whether batched."""
    a = img.numpy() if isinstance(img, Tensor) else np.asarray(img)
    batched = a.ndim == 4
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim == 3:
        if a.shape[2] == 1:
            a = np.repeat(a, 3, axis=2)
        if a.shape[2] != 3:
            raise ShapeError(f"MIPNet: {name} image must be HxW, HxWx1 or HxWx3, got shape {list(a.shape)}")
        a = a.transpose(2, 0, 1)[None]
    if a.ndim != 4 or a.shape[1] != 3:
        raise ShapeError(f"MIPNet: {name} must be HxWx3, HxW or (N,3,H,W), got shape {list(np.shape(img))}")
    if a.shape[2] < MIN_SIZE or a.shape[3] < MIN_SIZE:
        raise ShapeError(f"MIPNet: {name} image is {a.shape[2]}x{a.shape[3]}, smaller than {MIN_SIZE}x{MIN_SIZE} pixels")
    if not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ArgumentError(f"MIPNet: {name} has unsupported dtype {a.dtype}")
    a = a.astype(dtype)
    if not np.all(np.isfinite(a)):
        raise ArgumentError(f"MIPNet: {name} contains NaN or inf")
    return np.ascontiguousarray(a), batched


def _scaled_size(size: tuple[int, int], scale: float) -> tuple[int, int]:
    """(round(H·scale), round(W·scale)), checked to be a size the network takes."""
    if not (isinstance(scale, (int, float, np.floating, np.integer)) and np.isfinite(scale) and scale > 0):
        raise ArgumentError(f"MIPNet: scale must be a positive number, got {scale!r}")
    h, w = (max(1, round(s * float(scale))) for s in size)
    if min(h, w) < MIN_SIZE:
        raise ShapeError(f"MIPNet: scale {scale} makes the {size[0]}x{size[1]} images {h}x{w}, smaller than "
                         f"{MIN_SIZE}x{MIN_SIZE} pixels")
    return h, w


def _resize_images(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(N,3,H,W) 0..255 images resized to ``size`` (h, w): Pillow's bilinear filter, which widens its
    support when it shrinks (antialiased), per channel in float32."""
    h, w = size
    out = np.empty(images.shape[:2] + (h, w), dtype=images.dtype)
    for index in np.ndindex(*images.shape[:2]):
        channel = Image.fromarray(np.ascontiguousarray(images[index], dtype=np.float32))  # mode "F"
        out[index] = np.asarray(channel.resize((w, h), Image.BILINEAR))
    return out


def _padding(h: int, w: int) -> tuple[int, int, int, int]:
    """[left, right, top, bottom] replicate padding to a multiple of 16, split as architecture.md §2.1."""
    ph, pw = -h % DIVISOR, -w % DIVISOR
    return pw // 2, pw - pw // 2, ph // 2, ph - ph // 2


def _crop(pred: Tensor, pad: tuple[int, int, int, int], shape: tuple[int, ...]) -> Tensor:
    left, _, top, _ = pad
    if pred.shape[2:] == shape[2:]:
        return pred
    return pred[:, :, top:top + shape[2], left:left + shape[3]]


class _CorrelationOperands:
    """What the IP and RLS correlations of one level read, built once per level (architecture.md §2.5, §2.6).

    With the vertical constraint the flow's f_y is exactly 0, so the warp is a horizontal interpolation
    and the fused kernels take channels-last features, warping inside (no seed stack, no warped map).
    Without it, the seed stack is built and warped with grid_sample, as architecture.md §2.5 writes it."""

    def __init__(self, fl: Tensor, fr: Tensor, cfg: MIPNetConfig):
        self.cfg = cfg
        self.fused = cfg.vertical_constraint
        if self.fused:
            # (N, C, h, w) -> (N, h, w, C)
            self.fl, self.fr = ops.permute(fl, (0, 2, 3, 1)), ops.permute(fr, (0, 2, 3, 1))
        else:
            self.fl, self.fr = fl, fr
            self.stack = _seed_stack(fr) if cfg.use_ip else None

    def correlation(self, name: str, flow: Tensor) -> Tensor:
        if self.fused:
            fx = flow.numpy()[:, 0]
            if name == "ip":
                return ops.ip_warp_correlation(self.fl, self.fr, fx, groups=2)
            return ops.rls_warp_correlation(self.fl, self.fr, fx, rx=self.cfg.rx, ry=self.cfg.ry)
        grid = _sampling_grid(flow.numpy())
        if name == "ip":
            # C_IP = F_L · W(S(F_R, Δ), f): warp the stack of seed-shifted right features once (a.6)
            return ops.ip_correlation(self.fl, _warp(self.stack, grid), groups=2)
        # C_RLS = F_L · S(W(F_R, f), Δ): warp, then a (2rx+1)x(2ry+1) window of shifts (a.7)
        return ops.rls_correlation(self.fl, _warp(self.fr, grid), rx=self.cfg.rx, ry=self.cfg.ry)


def _seed_stack(fr: Tensor) -> Tensor:
    """cat[S_0..S_4] (N,5C,h,w): F_R shifted by the centre and the 4 diagonal seeds (ox, oy), clamped
    at the border by replicate padding (architecture.md §2.5)."""
    h, w = fr.shape[2], fr.shape[3]
    shifted = [fr]
    for ox, oy in ((-1, -1), (1, -1), (-1, 1), (1, 1)):
        l, r, t, b = max(-ox, 0), max(ox, 0), max(-oy, 0), max(oy, 0)
        padded = ops.pad(fr, [l, r, t, b], mode="replicate")
        # S(y, x) = F_R(y + oy, x + ox) = padded(y + oy + t, x + ox + l)
        shifted.append(padded[:, :, oy + t:oy + t + h, ox + l:ox + l + w])
    return ops.cat(shifted, 1)


def _sampling_grid(flow: np.ndarray) -> Tensor:
    """grid_sample grid (N,h,w,2) for positions p + f(p), normalised with align_corners=True:
    g = 2 (p + f) / max(size - 1, 1) - 1 (architecture.md §2.3)."""
    n, _, h, w = flow.shape
    ys, xs = np.meshgrid(np.arange(h, dtype=flow.dtype), np.arange(w, dtype=flow.dtype), indexing="ij")
    gx = 2 * (xs + flow[:, 0]) / max(w - 1, 1) - 1
    gy = 2 * (ys + flow[:, 1]) / max(h - 1, 1) - 1
    return Tensor(np.stack([gx, gy], axis=-1))


def _warp(features: Tensor, grid: Tensor) -> Tensor:
    """W(F, f): bilinear sampling with border padding and align_corners=True."""
    return ops.grid_sample(features, grid, mode="bilinear", padding_mode="border", align_corners=True)


def _vertical_constraint(delta: Tensor) -> Tensor:
    """(Δx, Δy) -> (Δx, 0): disparity moves only along the epipolar line."""
    dx = delta[:, 0:1]
    return ops.cat([dx, Tensor(np.zeros(dx.shape, dx.dtype))], 1)
