"""Peak memory of a MIPNet forward pass or training step, predicted before it runs.

:func:`estimate` counts, from the model's tensor sizes, the activations a pass keeps alive at its
peak: for a training step every activation the forward saves for backward, plus the parameter
gradients; for an eval pass the largest set of tensors alive at one moment. :func:`check` compares
the estimate with the memory the process may still use (the system's available memory as ``psutil``
reports it, ``MemAvailable`` on Linux; the cgroup limit; ``MIPNET_MEMORY_LIMIT``) and raises :class:`mipnet.errors.MemoryLimitError` instead of
letting the kernel kill the process. ``MIPNET_MEMORY_CHECK=0`` turns the check off.

The whole model of the network's memory is :func:`activation_bytes`: update it when an op starts to
save, or stops saving, a tensor. ``tests_py/test_memory.py`` compares it with the tensors the
autograd graph really holds and with the peak resident memory of fresh processes.
"""

from __future__ import annotations

import dataclasses
import os
import re
from typing import Any

import numpy as np

from ..errors import ArgumentError, MemoryLimitError
from .config import DIVISOR, MIPNetConfig

__all__ = ["MemoryEstimate", "estimate", "activation_bytes", "activation_terms", "available_memory", "check",
           "check_forward", "format_bytes", "measure_peak", "recompute_heads"]

MiB = 2**20
#: Resident memory of a fresh process after ``import mipnet`` (interpreter, numpy, Pillow, the Rust
#: core and its thread pool), before any model exists; measured on Linux x86-64 (48 MiB).
BASE_PROCESS_BYTES = 48 * MiB
#: glibc's malloc serves requests below its mmap threshold, which adapts up to 32 MiB on 64-bit
#: Linux, from its heap and keeps freed heap memory in the process; larger requests get their own
#: mapping, returned to the system when freed.
MMAP_THRESHOLD_MAX = 32 * MiB
#: Eval peak RSS / counted live tensors, measured from 64x96 to 768x1024 (1.6 to 2.2 when the
#: encoder's tensors are heap-sized: the memory the encoder freed stays in the process while the
#: 1/4-level stage allocates its own; 1.2 when they are mapped: kernel temporaries only).
EVAL_HEAP_FACTOR, EVAL_MMAP_FACTOR = 1.8, 1.25
#: Maps per image a training prediction's mask head and upsampling keep for backward at their level:
#: conv1's ReLU output (256) and the mask (144).
HEAD_CHANNELS = 400
#: Training keeps a level's prediction heads while all of them take at most this; above it they are
#: recomputed in the backward. At 384x512, batch 2, (6, 6) the heads take 472 MiB: keeping them cut the
#: recomputation from 1.19 to 0.25 s of op time (`python scripts/step_time.py --size 384 512 --batch 2
#: --iters 6 6 --profile`, AMD Zen 4, about 5% of the step) for about 320 MiB more peak (4,366 -> 4,676
#: MiB; torch takes about 10,500).
HEAD_KEEP_BYTES = 512 * MiB
#: The most bytes an eval process keeps of Winograd-transformed kernels (``src/ops/conv/winograd/cache.rs``).
KERNEL_CACHE_BYTES = 128 * MiB
#: Fewest tiles per image for a Winograd forward, by kernel shape (``Scheme::min_tiles`` in
#: ``src/ops/conv/winograd.rs``): F(4x4, 3x3) tiles 4x4 pixels, F(4, 5) 4 pixels along the kernel.
WINOGRAD_MIN_TILES = {(3, 3): 48, (1, 5): 32, (5, 1): 32}
#: Partial sums of a direct weight gradient beyond the first, kept per thread (``DW_GROUPS - 1`` and
#: ``PARTIALS`` in ``src/ops/conv.rs``), and each thread's im2col scratch (``SCRATCH_BYTES`` there).
DW_PARTIALS, CONV_SCRATCH_BYTES = 3, 4 * MiB


def recompute_heads(level_pixels: int, sub_updates: int, itemsize: int = 4) -> bool:
    """Whether training recomputes a level's prediction heads in the backward instead of keeping them:
    ``level_pixels`` = N * h * w of the level (the whole batch), ``sub_updates`` = predictions there."""
    return HEAD_CHANNELS * level_pixels * sub_updates * itemsize > HEAD_KEEP_BYTES


@dataclasses.dataclass(frozen=True)
class MemoryEstimate:
    """The predicted peak memory of one pass. Sizes in bytes."""

    mode: str  # "eval" or "train" (one training step: forward, loss and backward)
    height: int
    width: int
    batch: int
    iters: tuple[int, int]
    activations: int  # what the pass adds to the process at its peak
    baseline: int  # a fresh process holding the model (interpreter, libraries, weights)

    @property
    def total(self) -> int:
        """Peak resident memory of a fresh process running the pass."""
        return self.baseline + self.activations

    def describe(self) -> str:
        what = "eval forward" if self.mode == "eval" else "training step"
        return (f"{what} at {self.height}x{self.width} (HxW), batch {self.batch}, iters {self.iters}: "
                f"{format_bytes(self.activations)} for the pass, peak {format_bytes(self.total)} in a fresh process")


def format_bytes(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**30 else f"{n / MiB:.0f} MiB"


def activation_bytes(height: int, width: int, batch: int = 1, mode: str = "eval", iters: tuple[int, int] = (6, 6),
                     config: Any = None, itemsize: int = 4) -> int:
    """The bytes a MIPNet pass adds to the process at its peak: the sum of :func:`activation_terms`."""
    return int(sum(activation_terms(height, width, batch, mode, iters, config, itemsize).values()))


def activation_terms(height: int, width: int, batch: int = 1, mode: str = "eval", iters: tuple[int, int] = (6, 6),
                     config: Any = None, itemsize: int = 4, threads: int | None = None) -> dict[str, float]:
    """THE memory model of the network: the parts of a pass's peak, in bytes, by name.

    Every term is (channels per image) x (pixels at its level) x ``itemsize``, at the levels of the
    padded input (H, W multiples of 16): 1 (full resolution), 2, 4 (features, 1/4 updates) and 16.
    Eval: ``live`` (the largest set of tensors alive at once) and ``allocator`` (what the heap keeps
    and kernels add on top). Training: what the forward saves for backward (``encoder``, ``levels``,
    ``updates``, ``heads`` (see :func:`recompute_heads`), ``loss``), the ``backward`` working set and
    the ``kernel_buffers`` that the convolutions' weight gradients allocate at the size of a kernel.

    Parameters
    ----------
    height, width : int
        Input image size (before the padding to a multiple of 16).
    batch : int
        Image pairs per pass.
    mode : str
        ``"eval"`` (a forward without autograd) or ``"train"`` (forward, loss and backward).
    iters : (int, int)
        Iterations at 1/16 and at 1/4.
    config : MIPNetConfig, optional
        The architecture switches (default: the full model).
    itemsize : int
        4 (float32) or 8 (float64).
    threads : int, optional
        The kernels' threads (default: :func:`mipnet.get_num_threads`); each keeps its own buffers.

    Returns
    -------
    dict
        Name -> bytes.
    """
    cfg = config or MIPNetConfig()
    if mode not in ("eval", "train"):
        raise ArgumentError(f"memory: mode must be 'eval' or 'train', got {mode!r}")
    n16, n4 = iters
    hp, wp = -(-height // DIVISOR) * DIVISOR, -(-width // DIVISOR) * DIVISOR
    # pixels of one image at level s: (H / s) * (W / s)
    px = {s: (hp // s) * (wp // s) for s in (1, 2, 4, 16)}
    corr_rls = (2 * cfg.rx + 1) * (2 * cfg.ry + 1)

    def level(channels_per_image: float, s: int, images: int = batch) -> float:
        return channels_per_image * px[s] * images * itemsize

    if mode == "eval":
        # left and right as given, the normalised padded pair (2N images): 4 x 3 channels per pair
        images = level(12, 1)
        # encoder peak, the second iAFF gate of layer1 (2N images, 64 channels at 1/2): the block input,
        # y, x', z1, w2 and the gate's w2 x, 1 - w2, (1 - w2) x' (without iAFF: x, y, x', the sum, the ReLU)
        encoder = level((8 if cfg.use_aff else 5) * 64, 2, 2 * batch)
        if cfg.use_ip:
            # building the IP seed stack at 1/4: F_L, F_R, hidden, context (768), the 4 shifted copies of
            # F_R (1024), the concatenation (1280) and its copy to the standard layout (1280)
            stage4 = level(768 + 1024 + 2 * 1280, 4)
        else:
            # an RLS update at 1/4: F_L, F_R, hidden, context (768), warped F_R (256), the GRU's [h, x] (384 x 2)
            stage4 = level(768 + 256 + 2 * 384, 4)
        live = images + max(encoder, stage4)
        # the encoder's tensors decide whether the memory it frees stays in the heap (see EVAL_HEAP_FACTOR)
        heap_sized = 64 * px[2] * 2 * batch * itemsize < MMAP_THRESHOLD_MAX
        return {"live": live, "allocator": live * ((EVAL_HEAP_FACTOR if heap_sized else EVAL_MMAP_FACTOR) - 1)}

    # ---- training: what the forward saves for backward (each array once, however many ops save it)
    # stem: conv input (3 at 1/1), norm input and ReLU output (64 + 64 at 1/2). A ResBlock of c output
    # channels keeps norm1/norm2/norm3 inputs, y1, y2 and its output (6c); with iAFF also x' (c), the
    # input of iAFF's checkpoint (its own activations are recomputed in the backward)
    per_block = 7 if cfg.use_aff else 6
    encoder = (level(3, 1, 2 * batch) + level(128 + 2 * per_block * 64, 2, 2 * batch)
               + level(per_block * (2 * 96 + 2 * 128), 4, 2 * batch))
    fused = cfg.vertical_constraint
    if fused:
        # the fused warp + correlations keep channels-last F_L and F_R per level, and each call its f_x
        shared, warp_ip, warp_rls = 512, 1, 1
    else:
        # F_L (both correlations), the seed stack (IP grid_sample), F_R (RLS grid_sample); per call the
        # grid (2) and the warped map (1280 / 256)
        shared, warp_ip, warp_rls = 256 + (1280 if cfg.use_ip else 0) + (256 if cfg.use_rls else 0), 2 + 1280, 2 + 256
    # at 1/4 also tanh / ReLU of hidden and context; at 1/16 (unfused) the pooled hidden
    levels = level(shared + 256, 4) + level(shared + (0 if fused else 128), 16)
    # one IP call: the warp's (see above); motion encoder conv inputs (10 + 2), flow1's ReLU (64) and the
    # ReLU'd cat (128); ConvGRU [h, x] (352; [r h, x] is rebuilt in the backward), the z/r
    # pre-activations (256) and q's (128); head input h' (128), the disp head's ReLU (128); the
    # prediction's checkpoint input, the flow (2)
    ip_call = warp_ip + (12 + 64 + 128) + (352 + 256 + 128) + (128 + 128) + 2
    # one RLS call: the warp's; motion conv inputs (corr + 2), the corr1 / flow1 ReLUs (64 + 64) and the
    # ReLU'd cat (192); SepConvGRU, per pass [h, x] (384), z/r and q pre-activations (256 + 128);
    # h' (128), the disp head's ReLU (256); the flow (2)
    rls_call = warp_rls + (corr_rls + 2 + 128 + 192) + 2 * (384 + 256 + 128) + (128 + 256) + 2
    per_iter = (ip_call if cfg.use_ip else 0) + (rls_call if cfg.use_rls else 0)
    updates = level(per_iter * n16, 16) + level(per_iter * n4, 4)
    # the prediction heads' own activations, where they are kept rather than recomputed
    subs = cfg.use_ip + cfg.use_rls
    heads = sum(level(HEAD_CHANNELS * subs * n, s) for s, n in ((16, n16), (4, n4))
                if not recompute_heads(px[s] * batch, subs * n, itemsize))
    # the loss keeps each full-resolution prediction (1 channel) and the target and mask (~1.25)
    predictions = n16 * (cfg.use_ip + cfg.use_rls) + n4 * (cfg.use_ip + cfg.use_rls)
    loss = level(predictions + 1.25, 1)
    # backward, on top of the saved tensors while they are freed: the gradients accumulated for the
    # tensors all 1/4 iterations read (shared, hidden and context), those flowing through one update,
    # and a GRU pass's rebuilt [r h, x] with its gradient (2 x 384)
    backward = level(shared + 256 + max(ip_call if cfg.use_ip else 0, rls_call if cfg.use_rls else 0) + 2 * 384, 4)
    # one stack of convz and convr weights and biases per GRU pass, kept by its convolutions (shared by
    # all calls): the IP pass's 3x3 over 352 channels, each of the RLS's two passes 1x5 / 5x1 over 384
    ip_stack = 256 * (352 * 9 + 1) if cfg.use_ip else 0
    rls_stack = 256 * (384 * 5 + 1) if cfg.use_rls else 0
    stacked = itemsize * (ip_stack + 2 * rls_stack)
    # kernel-sized buffers of the weight gradients, at the largest kernel (a stack above, else a
    # prediction head's 3x3 128 -> 256): per thread the kept partial sums and the im2col scratch; once
    # the gradient and its reordered copy (direct) or the transformed dU (Winograd F(4x4, 3x3): 36
    # values per 9 taps)
    largest = itemsize * max(ip_stack, rls_stack, 256 * 128 * 9)
    kernel_buffers = (threads or _threads()) * (DW_PARTIALS * largest + CONV_SCRATCH_BYTES) + 4 * largest
    return {"encoder": encoder, "levels": levels, "updates": updates, "heads": heads, "loss": loss, "stacked": stacked,
            "backward": backward, "kernel_buffers": kernel_buffers}


def _threads() -> int:
    from .. import get_num_threads

    return get_num_threads()


def kept_kernel_bytes(model: Any, height: int, width: int) -> int:
    """Bytes an eval process keeps for the float32 Winograd kernels of ``model`` (a MIPNet) on images of
    ``height`` x ``width``: each 3x3, 1x5 or 5x1 kernel of 32 channels or more in and out whose
    convolution at the 1/4 level has enough tiles for Winograd, copied, and transformed into 36 (3x3) or
    8 values per channel pair, its output channels padded to 8."""
    # tiles at the 1/4 level (h4 x w4 = height/4 x width/4): 4x4 pixels for 3x3, 4 along the kernel for 1x5, 5x1
    h4, w4 = height // 4, width // 4
    tiles = {(3, 3): (h4 // 4) * (w4 // 4), (1, 5): h4 * (w4 // 4), (5, 1): (h4 // 4) * w4}
    total = 0
    for p in model.parameters():
        shape = p.data.shape
        if (len(shape) == 4 and min(shape[:2]) >= 32 and shape[2:] in tiles
                and tiles[shape[2:]] >= WINOGRAD_MIN_TILES[shape[2:]]):
            cout, cin, kh, kw = shape
            xi = 36 if (kh, kw) == (3, 3) else 8
            total += 4 * (cout * cin * kh * kw + -(-cout // 8) * 8 * cin * xi)
    return total


def model_bytes(model: Any) -> int:
    """Bytes of the parameters and buffers of ``model`` (default: a full MIPNet of ``itemsize``),
    counted without copying them."""
    return (sum(p.data.nbytes for p in model.parameters())
            + sum(np.asarray(b).nbytes for _, b in model.named_buffers()))


def estimate(height: int, width: int, batch: int = 1, mode: str = "eval", iters: tuple[int, int] = (6, 6),
             model: Any = None) -> MemoryEstimate:
    """The predicted peak memory of a pass of ``model`` (a MIPNet) on images of ``height`` x ``width``.
    A training step adds the parameter gradients to the saved activations."""
    if model is None:
        raise ArgumentError("memory.estimate: pass the model (e.g. mipnet.MIPNet()) whose pass to estimate")
    config = model.config
    itemsize = model.dtype.itemsize
    weights = model_bytes(model)
    extra = activation_bytes(height, width, batch, mode, tuple(iters), config, itemsize)
    if mode == "train":
        extra += weights  # the gradient of every parameter
    elif itemsize == 4:
        # inference keeps the transformed kernels of the convolutions that take Winograd
        extra += min(KERNEL_CACHE_BYTES, kept_kernel_bytes(model, height, width))
    return MemoryEstimate(mode, height, width, batch, (int(iters[0]), int(iters[1])), int(extra),
                          BASE_PROCESS_BYTES + weights)


# ---------------------------------------------------------------------------- available memory

_UNITS = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}


def parse_size(text: str) -> int:
    """Bytes from ``"123456"``, ``"512M"``, ``"8G"``, ``"1.5GiB"`` (binary units)."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kKmMgGtT]?)(i?[bB])?\s*", text)
    if not match:
        raise ArgumentError(f"memory size {text!r}: expected a number of bytes with an optional K, M, G or T")
    return int(float(match.group(1)) * _UNITS[match.group(2).lower()])


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read()
    except OSError:
        return None


def _resident_bytes() -> int:
    """This process's resident set size (``VmRSS`` on Linux)."""
    import psutil

    return int(psutil.Process().memory_info().rss)


def _cgroup_room() -> tuple[int, str] | None:
    """(limit - usage, which limit) of this process's memory cgroup (v2, else v1), if it has a limit.

    Read from the cgroup files by hand: psutil reports the host's memory, not a container's limit."""
    membership = _read("/proc/self/cgroup") or ""
    v2 = re.search(r"^0::(.*)$", membership, re.M)
    if v2:
        base = "/sys/fs/cgroup" + v2.group(1).rstrip("/")
        for directory in (base, "/sys/fs/cgroup"):
            limit, usage = _read(f"{directory}/memory.max"), _read(f"{directory}/memory.current")
            if limit and usage and limit.strip() != "max":
                return int(limit) - int(usage), f"cgroup memory.max {format_bytes(int(limit))}"
    limit, usage = _read("/sys/fs/cgroup/memory/memory.limit_in_bytes"), _read("/sys/fs/cgroup/memory/memory.usage_in_bytes")
    if limit and usage and int(limit) < 2**60:
        return int(limit) - int(usage), f"cgroup memory.limit_in_bytes {format_bytes(int(limit))}"
    return None


def available_memory() -> tuple[int, str] | None:
    """(bytes this process may still allocate, where the bound comes from), or None where it cannot be
    told: the least of the system's available memory (``psutil.virtual_memory().available``, which is
    ``MemAvailable`` of ``/proc/meminfo`` on Linux), the cgroup's room and ``MIPNET_MEMORY_LIMIT`` (a cap
    on this process's resident memory, e.g. ``8G``) minus what it uses."""
    import psutil

    bounds = []
    try:
        bounds.append((int(psutil.virtual_memory().available), "available system memory"))
    except (OSError, psutil.Error):  # no /proc mounted
        pass
    cgroup = _cgroup_room()
    if cgroup:
        bounds.append(cgroup)
    cap = os.environ.get("MIPNET_MEMORY_LIMIT")
    if cap:
        limit = parse_size(cap)
        bounds.append((limit - _resident_bytes(), f"MIPNET_MEMORY_LIMIT={cap}"))
    return min(bounds) if bounds else None


def check(needed: MemoryEstimate) -> None:
    """Raises :class:`MemoryLimitError` if the pass needs more than :func:`available_memory` (unless
    ``MIPNET_MEMORY_CHECK=0``)."""
    if os.environ.get("MIPNET_MEMORY_CHECK", "1") == "0":
        return
    available = available_memory()
    if available is None or needed.activations <= available[0]:
        return
    room, source = available
    what = "eval forward" if needed.mode == "eval" else "training step"
    raise MemoryLimitError(
        f"MIPNet {what} at {needed.height}x{needed.width} (HxW), batch {needed.batch}, iters {needed.iters} "
        f"needs about {format_bytes(needed.activations)} more memory, but only {format_bytes(max(room, 0))} is "
        f"available ({source}); use smaller images (in eval mode scale=0.5, `mipnet infer --scale 0.5`), a smaller "
        f"batch or fewer iterations (MIPNET_MEMORY_CHECK=0 skips this check)", estimate=needed.activations,
        available=max(room, 0))


def check_forward(model: Any, shape: tuple[int, ...], iters: tuple[int, int], training: bool) -> None:
    """The check :meth:`MIPNet.forward` runs before a pass on an (N, 3, H, W) input."""
    n, _, h, w = shape
    check(estimate(h, w, n, "train" if training else "eval", iters, model))


# ------------------------------------------------------------------------------ measured peaks

# Runs in a fresh process: builds a float32 MIPNet, runs one pass, prints its peak resident memory.
_MEASURE = r"""
import json, sys
import numpy as np
import mipnet
mode, h, w, n, n16, n4 = sys.argv[1], *map(int, sys.argv[2:7])
mipnet.manual_seed(0)
model = mipnet.MIPNet()
rng = np.random.default_rng(0)
left = rng.uniform(0, 255, (n, 3, h, w)).astype(np.float32)
right = np.roll(left, -4, axis=3)
if mode == "eval":
    model.eval()(left, right, iters=(n16, n4))
else:
    gt = np.full((n, 1, h, w), 4.0, np.float32)
    mipnet.model.losses.sequence_loss(model.train()(left, right, iters=(n16, n4)), gt, gt > 0).backward()
# VmHWM, the peak of this process's own memory map: ru_maxrss would also count the parent's resident
# memory at fork time, which Linux carries over exec (psutil has no peak resident size on Linux)
hwm = next(line for line in open("/proc/self/status") if line.startswith("VmHWM:"))
print(json.dumps({"peak": int(hwm.split()[1]) * 1024}))
"""


def measure_peak(height: int, width: int, batch: int = 1, mode: str = "eval", iters: tuple[int, int] = (6, 6),
                 threads: int | None = None) -> int:
    """Peak resident memory (bytes, ``VmHWM``; Linux) of a fresh Python process that runs one pass of a
    float32 MIPNet: what :meth:`MemoryEstimate.total` predicts. The child runs the memory check, so a
    pass too large for this machine raises instead of exhausting it."""
    import json
    import subprocess
    import sys

    env = dict(os.environ)
    if threads:
        env["MIPNET_NUM_THREADS"] = str(threads)
    args = [mode, height, width, batch, *iters]
    done = subprocess.run([sys.executable, "-c", _MEASURE, *map(str, args)], capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"measure_peak {mode} {height}x{width}: the child failed: {done.stderr.strip()[-500:]}")
    return int(json.loads(done.stdout.strip().splitlines()[-1])["peak"])
