"""Benchmarks of mipnet against torch on the same inputs and thread count.

Usage::

    python -m mipnet.bench ops [--threads 2] [--repeat 15] [--warmup 1] [--filter conv] [--peak GFLOPS]
                               [--step 128x256x4:3,3]
    python -m mipnet.bench model [--threads 2] [--sizes 384x512 768x1024 1088x1920]
                                 [--train 384x512x2:6,6 128x256x4:3,3] [--engines ...] [--profile]
    python -m mipnet.bench precision [--size 384x512] [--batch 2] [--iters 6,6] [--inputs scenes|noise]

``precision`` (:mod:`mipnet.bench.precision`) prints float32's error against float64 per layer group
of a training-mode forward, mipnet beside torch. ``ops`` times each kernel row (forward, or forward + backward) with mipnet and with torch and prints
a table: op, shape, mipnet ms and torch ms (medians of runs in alternating blocks, each after a
warm-up), their ratio, and for rows with a FLOP count the achieved GFLOP/s and its share of the FMA
peak. The header names the CPU, the ISA path and GEMM plan mipnet runs, and the peak measured at
start (``_core.fma_peak_gflops``: independent FMA chains on one core and on ``--threads`` threads);
``--peak`` replaces the measured figure. ``--step HxWxBATCH:N16,N4`` replaces the fixed rows with
every distinct convolution of one mipnet training step of that size (forward + backward, with its
calls per step) and sums them, to compare the step's convolution time with torch's on the same
shapes. torch is needed for the comparison; without it the
command says so and exits with status 1.

Adding a row is one line in :func:`ops_cases`: a :class:`BenchCase` with a name, a shape string, a
function making the numpy inputs, and the mipnet and torch calls taking one tensor per input.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

import mipnet
import mipnet.ops as M
from mipnet import _core
from mipnet.bench.model import ENGINES
from mipnet.bench.machine import machine_header
from mipnet.bench.precision import main as run_precision, parse_args as precision_args


#: Pause after each block of runs of one library (longer than OpenMP's spin-wait).
_PAUSE_S = 0.3
#: Least warm-up time at the start of each block.
_WARM_S = 0.2


@dataclass
class BenchCase:
    """One benchmark row.

    Attributes:
        name: the op as printed ("conv2d 3x3").
        shape_str: the sizes as printed.
        make_inputs: numpy inputs from a seeded generator (float32 unless the row says otherwise).
        mipnet_fn: the mipnet call, one ``mipnet.Tensor`` per input; returns a Tensor (or an array
            for forward-only rows).
        torch_fn: the same computation in torch, one ``torch.Tensor`` per input.
        backward: time forward + backward (to every input in ``grad_inputs``) instead of forward.
        flops: floating-point operations of one timed call (None: no GFLOP/s column).
        grad_inputs: which inputs get gradients when ``backward`` (None: all).
    """

    name: str
    shape_str: str
    make_inputs: Callable[[np.random.Generator], list[np.ndarray]]
    mipnet_fn: Callable[..., Any]
    torch_fn: Callable[..., Any]
    backward: bool = False
    flops: float | None = None
    grad_inputs: Sequence[int] | None = None


def _randn(*shape: int) -> Callable[[np.random.Generator], np.ndarray]:
    return lambda rng: rng.standard_normal(shape, dtype=np.float32)


def conv_case(n: int, cin: int, cout: int, h: int, w: int, k: int | tuple[int, int], stride: int = 1,
              backward: bool = False, torch: Any = None, padding: tuple[int, int] | None = None) -> BenchCase:
    """A conv2d row: k x k (or kh x kw) kernel, padding k // 2 per axis (or ``padding``), with bias."""
    kh, kw = (k, k) if isinstance(k, int) else k
    pad = (kh // 2, kw // 2) if padding is None else padding
    ho, wo = (h + 2 * pad[0] - kh) // stride + 1, (w + 2 * pad[1] - kw) // stride + 1
    fwd_flops = 2.0 * n * cout * cin * kh * kw * ho * wo
    F = torch.nn.functional
    return BenchCase(
        f"conv2d {kh}x{kw}" + (f" s{stride}" if stride != 1 else "") + (" fwd+bwd" if backward else " fwd"),
        f"N={n} {cin}->{cout} {h}x{w}",
        lambda rng: [_randn(n, cin, h, w)(rng), _randn(cout, cin, kh, kw)(rng) * np.float32(0.05), _randn(cout)(rng)],
        lambda x, wt, b: M.conv2d(x, wt, b, stride=stride, padding=pad),
        lambda x, wt, b: F.conv2d(x, wt, b, stride=stride, padding=pad),
        backward=backward,
        flops=fwd_flops * (3 if backward else 1),  # backward: dX and dW cost one forward each
    )


def _horizontal_grid(n: int, h: int, w: int) -> Callable[[np.random.Generator], np.ndarray]:
    """A warp grid p + f with f_x = -disparity (0..20 px), f_y = 0, normalised with align_corners=True."""
    def make(rng: np.random.Generator) -> np.ndarray:
        xs = np.arange(w) - rng.uniform(0, 20, size=(n, h, w))
        ys = np.broadcast_to(np.arange(h)[:, None], (n, h, w))
        return np.stack([2 * xs / (w - 1) - 1, 2 * ys / (h - 1) - 1], -1).astype(np.float32)
    return make


def _torch_stereo_ops(torch: Any) -> dict[str, Callable[..., Any]]:
    """The torch expressions (architecture.md §2.5, §2.6, §2.8) of the fused stereo kernels."""
    F = torch.nn.functional

    def ip(fl, stack):
        n, c, h, w = fl.shape
        # (N,5,2,C/2,h,w) * (N,1,2,C/2,h,w) -> mean over C/2 -> channel 5*g + s
        prod = stack.view(n, 5, 2, c // 2, h, w) * fl.view(n, 1, 2, c // 2, h, w)
        return prod.mean(3).permute(0, 2, 1, 3, 4).reshape(n, 10, h, w)

    def rls(fl, warped, rx=3, ry=1):
        h, w = fl.shape[2:]
        p = F.pad(warped, [rx, rx, ry, ry], mode="replicate")
        return torch.cat([(fl * p[:, :, j:j + h, i:i + w]).mean(1, keepdim=True)
                          for i in range(2 * rx + 1) for j in range(2 * ry + 1)], 1)

    def convex(flow, mask, r=4):
        n, d, h, w = flow.shape
        weights = torch.softmax(mask.view(n, 1, 9, r, r, h, w), dim=2)
        up = F.unfold(r * flow, [3, 3], padding=1).view(n, d, 9, 1, 1, h, w)
        # (N,D,r,r,h,w) -> (N,D,h,r,w,r) -> (N,D,r*h,r*w)
        return (weights * up).sum(2).permute(0, 1, 4, 2, 5, 3).reshape(n, d, r * h, r * w)

    return {"ip": ip, "rls": rls, "convex": convex}


def stereo_cases(torch: Any) -> list[BenchCase]:
    """The stereo-op rows at MIPNet's 1/4 level of a 384x512 image (96x128)."""
    t = _torch_stereo_ops(torch)
    F = torch.nn.functional
    h, w = 96, 128
    cases = []
    for backward in (False, True):
        mode = " fwd+bwd" if backward else " fwd"
        cases += [
            BenchCase("grid_sample border" + mode, f"1x1280x{h}x{w}", lambda rng: [_randn(1, 1280, h, w)(rng), _horizontal_grid(1, h, w)(rng)],
                      lambda x, g: M.grid_sample(x, g, padding_mode="border", align_corners=True),
                      lambda x, g: F.grid_sample(x, g, padding_mode="border", align_corners=True),
                      backward=backward, grad_inputs=[0]),
            BenchCase("ip_correlation" + mode, f"1x256 . 1x1280 @ {h}x{w}", lambda rng: [_randn(1, 256, h, w)(rng), _randn(1, 1280, h, w)(rng)],
                      lambda a, b: M.ip_correlation(a, b, groups=2), t["ip"], backward=backward),
            BenchCase("rls_correlation 7x3" + mode, f"1x256 @ {h}x{w}", lambda rng: [_randn(1, 256, h, w)(rng), _randn(1, 256, h, w)(rng)],
                      lambda a, b: M.rls_correlation(a, b, rx=3, ry=1), t["rls"], backward=backward),
            BenchCase("convex_upsample x4" + mode, f"1x2 + 1x144 @ {h}x{w}", lambda rng: [_randn(1, 2, h, w)(rng), _randn(1, 144, h, w)(rng)],
                      lambda f, m: M.convex_upsample(f, m, rate=4), t["convex"], backward=backward),
        ]
    return cases


def ops_cases(torch: Any) -> list[BenchCase]:
    """The rows of ``ops``: one line per case."""
    m, k, n = 1024, 1152, 4096
    return [
        BenchCase("sgemm (gemm.rs)", f"{m}x{k} @ {k}x{n}", lambda rng: [_randn(m, k)(rng), _randn(k, n)(rng)],
                  lambda a, b: _core.gemm_fwd(a.numpy(), b.numpy()), torch.matmul, flops=2.0 * m * k * n),
        # the model's convolutions at 384x512: encoder and GRU at 1/4 (96x128), ConvGRU at 1/16, heads, stem
        *(conv_case(2, 128, 128, 96, 128, 3, backward=bwd, torch=torch) for bwd in (False, True)),
        *(conv_case(4, 128, 128, 96, 128, 3, backward=bwd, torch=torch) for bwd in (False, True)),
        *(conv_case(1, 128, 256, 96, 128, 3, backward=bwd, torch=torch) for bwd in (False, True)),
        *(conv_case(2, 352, 128, 24, 32, 3, backward=bwd, torch=torch) for bwd in (False, True)),
        *(conv_case(2, 384, 128, 96, 128, (1, 5), backward=bwd, torch=torch) for bwd in (False, True)),
        *(conv_case(2, 384, 128, 96, 128, (5, 1), backward=bwd, torch=torch) for bwd in (False, True)),
        *(conv_case(1, 256, 144, 96, 128, 1, backward=bwd, torch=torch) for bwd in (False, True)),
        *(conv_case(2, 3, 64, 384, 512, 7, stride=2, backward=bwd, torch=torch) for bwd in (False, True)),
        *stereo_cases(torch),
    ]


def step_conv_cases(spec: str, torch: Any) -> list[tuple[BenchCase, int]]:
    """The distinct convolutions of one mipnet training step (``HxWxBATCH:N16,N4``, random weights and
    inputs as in ``bench model``) as forward + backward rows, each with how often the step runs it,
    most frequent first."""
    import mipnet.ops._conv as conv_module
    from mipnet.bench.model import _parse_train

    h, w, n, iters = _parse_train(spec)
    counts: dict[tuple, int] = {}
    core = conv_module._core

    class _Recorder:
        """``_core`` for the conv module, counting each forward call's geometry."""

        def __getattr__(self, name: str) -> Any:
            return getattr(core, name)

        def conv2d_fwd(self, x, weight, bias, stride, padding, **kwargs):
            key = (x.shape, weight.shape, tuple(stride), tuple(padding))
            counts[key] = counts.get(key, 0) + 1
            return core.conv2d_fwd(x, weight, bias, stride, padding, **kwargs)

    rng = np.random.default_rng(0)
    left = rng.uniform(0, 255, (n, 3, h, w)).astype(np.float32)
    gt = np.full((n, 1, h, w), 4.0, np.float32)
    model = mipnet.MIPNet().train()
    conv_module._core = _Recorder()
    try:
        preds = model(left, np.roll(left, -4, axis=3), iters=iters)
        mipnet.model.losses.sequence_loss(preds, gt, gt > 0).backward()
    finally:
        conv_module._core = core
    rows = []
    for (xs, ws, stride, padding), count in sorted(counts.items(), key=lambda kv: -kv[1] * np.prod(kv[0][1])):
        case = conv_case(xs[0], xs[1], ws[0], xs[2], xs[3], (ws[2], ws[3]), stride[0], backward=True, torch=torch,
                         padding=padding)
        case.shape_str += f" x{count}"
        rows.append((case, count))
    return rows


def _median_ms(runs: Sequence[Callable[[], Any]], warmup: int, repeat: int, rounds: int = 3) -> list[float]:
    """Median wall time in ms of each closure. The closures take turns in `rounds` blocks (a burst of
    load from elsewhere on the machine hits all of them alike); each block starts with `warmup`
    untimed runs (and at least _WARM_S of them) and ends with a pause, so that a library's idle worker threads (torch's OpenMP
    threads spin-wait after a parallel region) have gone to sleep before the next one is timed."""
    times: list[list[float]] = [[] for _ in runs]
    per_round = max(1, -(-repeat // rounds))
    for _ in range(rounds):
        for run, ts in zip(runs, times):
            # warm up for `warmup` runs and at least _WARM_S (clocks and caches after the pause)
            t_end, done = time.perf_counter() + _WARM_S, 0
            while done < warmup or time.perf_counter() < t_end:
                run()
                done += 1
            for _ in range(per_round):
                t0 = time.perf_counter()
                run()
                ts.append(time.perf_counter() - t0)
            time.sleep(_PAUSE_S)
    return [1e3 * statistics.median(ts) for ts in times]


def _runner(case: BenchCase, inputs: list[np.ndarray], lib: str, torch: Any) -> Callable[[], Any]:
    """A closure running the case once with one library (forward, or forward + backward)."""
    grad_idx = range(len(inputs)) if case.grad_inputs is None else case.grad_inputs
    if lib == "torch":
        tensors = [torch.from_numpy(a).requires_grad_(case.backward and i in grad_idx) for i, a in enumerate(inputs)]
        fn = case.torch_fn
    else:
        tensors = [mipnet.tensor(a, requires_grad=case.backward and i in grad_idx) for i, a in enumerate(inputs)]
        fn = case.mipnet_fn
    if not case.backward:
        return lambda: fn(*tensors)
    out_shape = tuple(fn(*tensors).shape)
    g = np.random.default_rng(1).uniform(-1, 1, size=out_shape).astype(inputs[0].dtype)
    g_lib = torch.from_numpy(g) if lib == "torch" else g

    def run() -> None:
        for t in tensors:
            t.grad = None
        fn(*tensors).backward(g_lib)

    return run


def run_ops(args: argparse.Namespace, torch: Any) -> int:
    if args.step:
        counted = step_conv_cases(args.step, torch)
    else:
        counted = [(c, 0) for c in ops_cases(torch)]
    counted = [(c, k) for c, k in counted if not args.filter or args.filter in f"{c.name} {c.shape_str}"]
    header_text, peak = machine_header(args.threads, args.peak)
    header = ["op", "shape", "mipnet ms", "torch ms", "ratio", "GFLOP/s", f"% of {peak:.0f}"]
    rows, step_ms = [], [0.0, 0.0]
    for case, count in counted:
        inputs = case.make_inputs(np.random.default_rng(0))
        ours, theirs = _median_ms([_runner(case, inputs, lib, torch) for lib in ("mipnet", "torch")],
                                  args.warmup, args.repeat)
        step_ms = [step_ms[0] + count * ours, step_ms[1] + count * theirs]
        gflops = case.flops / ours / 1e6 if case.flops else None
        rows.append([case.name, case.shape_str, f"{ours:.2f}", f"{theirs:.2f}", f"{ours / theirs:.2f}",
                     "" if gflops is None else f"{gflops:.0f}", "" if gflops is None else f"{100 * gflops / peak:.0f}%"])
        print(f"  done: {case.name} {case.shape_str}", file=sys.stderr, flush=True)
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    line = lambda r: "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths)))  # noqa: E731
    print(header_text)
    print(f"threads={args.threads}  (median of {args.repeat} runs in 3 alternating blocks, each after {args.warmup} warm-up; ratio = mipnet / torch)")
    print(line(header))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print(line(r))
    if args.step:
        print(f"the convolutions of one training step {args.step} (forward + backward, x: calls per step), summed: "
              f"mipnet {step_ms[0] / 1e3:.2f} s, torch {step_ms[1] / 1e3:.2f} s ({step_ms[1] / max(step_ms[0], 1e-9):.2f}x)")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mipnet.bench", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    ops = sub.add_parser("ops", help="per-kernel timings against torch")
    ops.add_argument("--threads", type=int, default=2, help="threads for mipnet and torch (default 2)")
    ops.add_argument("--repeat", type=int, default=15, help="timed runs per row and library (default 15)")
    ops.add_argument("--warmup", type=int, default=1, help="untimed runs before each block (default 1)")
    ops.add_argument("--filter", default="", help="only rows whose op or shape contains this text")
    ops.add_argument("--step", metavar="HxWxBATCH:N16,N4", default=None,
                     help="instead of the fixed rows: every distinct convolution of one training step of that "
                          "size (forward + backward), with its count per step and the step's sum")
    ops.add_argument("--peak", type=float, default=None,
                     help="GFLOP/s taken as 100%% (default: the FMA peak measured on --threads threads)")
    model = sub.add_parser("model", help="whole-network timings and peak memory of every engine (mipnet, torch, "
                                          "OpenVINO, onnxruntime)")
    model.add_argument("--threads", type=int, default=2, help="threads for every engine (default 2)")
    model.add_argument("--sizes", nargs="*", default=["384x512", "768x1024", "1088x1920"], help="eval sizes HxW")
    model.add_argument("--train", nargs="*", default=["384x512x2:6,6", "128x256x4:3,3"],
                       help="train steps HxWxBATCH:N16,N4 (default 384x512x2:6,6 128x256x4:3,3)")
    model.add_argument("--engines", nargs="+", default=list(ENGINES), choices=list(ENGINES))
    model.add_argument("--warmup", type=int, default=1, help="untimed runs before the timed one (default 1)")
    model.add_argument("--rounds", type=int, default=1,
                       help="fresh runs per engine and case, the engines taking turns; the table gives the median "
                            "(default 1)")
    model.add_argument("--profile", action="store_true", help="also print mipnet's profile of eval and train")
    model.add_argument("--precision", nargs="+", default=["fp32"], choices=("fp32", "bf16"),
                       help="bf16 adds a row of mipnet under mipnet.autocast(dtype='bfloat16') to each eval case "
                            "(default fp32 only)")
    precision = sub.add_parser("precision", help="float32 against float64 per layer group in a training-mode "
                                                  "forward, mipnet beside torch")
    precision_args(precision)
    args = parser.parse_args(argv)
    if args.command == "precision":
        return run_precision(args)
    if args.command == "model":
        from .model import run as run_model

        hw = lambda s: tuple(int(v) for v in s.lower().split("x"))  # noqa: E731
        return run_model(args.threads, [hw(s) for s in args.sizes], args.train, args.engines, args.profile, args.warmup,
                         max(1, args.rounds), args.precision)
    try:
        import torch
    except ImportError:
        print("mipnet.bench: torch is needed for the comparison rows; install it (pip install torch)", file=sys.stderr)
        return 1
    torch.set_num_threads(args.threads)
    mipnet.set_num_threads(args.threads)
    return run_ops(args, torch)

