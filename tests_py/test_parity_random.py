"""Op parity with torch at random shapes (hypothesis), one test per op family.

Each example draws shapes, kernel sizes, strides, paddings and the other arguments the op takes, a
dtype (float32 / float64), input values, and a memory layout in which every kernel receives its array
arguments, the upstream gradients included: C order, Fortran order, a strided, a reversed or a
transposed view. The forward and the gradients of every input are compared with torch at the
tolerances of ``helpers.TOL``. A failure shrinks to a minimal case (smallest shapes, simplest layout).

The number of examples per family is bounded (``EXAMPLES``) to keep the file within its CI budget;
``MIPNET_HYPOTHESIS_SCALE`` multiplies them for a longer run.
"""

from __future__ import annotations

import contextlib

import numpy as np

from helpers import check_op, require, require_torch

require("hypothesis")
torch = require_torch()
from hypothesis import given, strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402

import mipnet.ops as M  # noqa: E402
from mipnet import _core  # noqa: E402
from fuzzing import fuzz_settings  # noqa: E402
from reference import convex_upsample as convex_torch, ip_correlation as ip_torch  # noqa: E402
from reference import rls_correlation as rls_torch  # noqa: E402

F = torch.nn.functional

#: Examples per op family (the counts the issue's closing note reports).
EXAMPLES = {"conv2d": 250, "norm": 150, "pool": 150, "pad": 100, "grid_sample": 150, "interpolate": 120,
            "unfold_fold": 100, "softmax": 100, "elementwise": 200, "cat_slice": 100, "correlation": 150,
            "convex_upsample": 100, "loss": 100}

LAYOUTS = ("c", "fortran", "strided", "reversed", "transposed")


def in_layout(a, layout: str):
    """The values of ``a`` as an array of the given memory layout (a view where the layout needs one)."""
    if not isinstance(a, np.ndarray) or a.ndim == 0 or layout == "c":
        return a
    if layout == "fortran":
        return np.asfortranarray(a)
    if layout == "strided":
        # every other element of a buffer twice as wide along the last axis
        buffer = np.zeros(a.shape[:-1] + (2 * a.shape[-1],), a.dtype)
        buffer[..., ::2] = a
        return buffer[..., ::2]
    if layout == "reversed":
        return np.flip(np.flip(a, -1).copy(), -1)
    # transposed: the last two axes swapped in memory and swapped back in the view
    return np.swapaxes(np.ascontiguousarray(np.swapaxes(a, -1, -2)), -1, -2) if a.ndim >= 2 else a


@contextlib.contextmanager
def kernels_see(layout: str):
    """Every ``mipnet._core`` kernel called inside receives its array arguments (and arrays in list
    arguments) in ``layout``."""
    names = [n for n in dir(_core) if n.endswith(("_fwd", "_bwd")) or n == "sum_to_shape"]
    originals = {n: getattr(_core, n) for n in names}

    def wrap(fn):
        def call(*args, **kwargs):
            args = [[in_layout(x, layout) for x in a] if isinstance(a, list) else in_layout(a, layout) for a in args]
            return fn(*args, **{k: in_layout(v, layout) for k, v in kwargs.items()})
        return call

    try:
        for n in names:
            setattr(_core, n, wrap(originals[n]))
        yield
    finally:
        for n in names:
            setattr(_core, n, originals[n])


dtypes = st.sampled_from([np.float32, np.float64])
layouts = st.sampled_from(LAYOUTS)
seeds = st.integers(0, 2**16)


def values(shape, dtype, seed, low=-2.0, high=2.0):
    return np.random.default_rng(seed).uniform(low, high, size=shape).astype(dtype)


def parity(inputs, torch_fn, mipnet_fn, dtype, layout, seed, grad_inputs=None, **tol):
    with kernels_see(layout):
        check_op(inputs, torch_fn, mipnet_fn, grad_inputs=grad_inputs, dtype=dtype, seed=seed, **tol)


# ------------------------------------------------------------------------------------------ conv2d

@st.composite
def conv_cases(draw):
    k = (draw(st.integers(1, 5)), draw(st.integers(1, 5)))
    stride = (draw(st.integers(1, 3)), draw(st.integers(1, 3)))
    pad = (draw(st.integers(0, 3)), draw(st.integers(0, 3)))
    # the padded input must hold one kernel: H + 2p >= k
    hw = tuple(draw(st.integers(max(1, k[i] - 2 * pad[i]), 12)) for i in range(2))
    n, cin, cout = draw(st.integers(1, 2)), draw(st.integers(1, 6)), draw(st.integers(1, 6))
    return (n, cin) + hw, (cout, cin) + k, stride, pad, draw(st.booleans())


@fuzz_settings(EXAMPLES["conv2d"])
@given(case=conv_cases(), dtype=dtypes, layout=layouts, seed=seeds)
def test_conv2d(case, dtype, layout, seed):
    xs, ws, stride, pad, bias = case
    # weights scaled like a trained layer (1 / sqrt(fan-in)) so that float32 sums stay within tolerance
    w = values(ws, dtype, seed + 1) / np.sqrt(np.prod(ws[1:]))
    inputs = [values(xs, dtype, seed), w] + ([values(ws[:1], dtype, seed + 2)] if bias else [])
    parity(inputs, lambda *a: F.conv2d(*a, stride=stride, padding=pad),
           lambda *a: M.conv2d(*a, stride=stride, padding=pad), dtype, layout, seed)


# -------------------------------------------------------------------------------------------- norms

spatial = st.tuples(st.integers(1, 3), st.integers(1, 4), st.integers(1, 7), st.integers(1, 7))


@fuzz_settings(EXAMPLES["norm"])
@given(shape=spatial, kind=st.sampled_from(["instance", "batch-train", "batch-eval"]), affine=st.booleans(),
       stats=st.booleans(), momentum=st.floats(0.05, 0.9), eps=st.sampled_from([1e-5, 1e-3]),
       dtype=dtypes, layout=layouts, seed=seeds)
def test_norms(shape, kind, affine, stats, momentum, eps, dtype, layout, seed):
    n, c, h, w = shape
    # torch needs more than one value per channel to normalise with batch statistics
    if kind == "instance" and h * w < 2 or kind == "batch-train" and n * h * w < 2:
        shape = (n, c, h, w + 1)
    params = [values((c,), dtype, seed + 1, 0.5, 1.5), values((c,), dtype, seed + 2)] if affine else []
    x = values(shape, dtype, seed)
    if kind == "instance":
        parity([x] + params, lambda x, *p: F.instance_norm(x, None, None, *p, eps=eps),
               lambda x, *p: M.instance_norm(x, None, None, *p, eps=eps), dtype, layout, seed)
        return
    training = kind == "batch-train"
    stats = stats or not training  # eval mode needs running statistics
    running = [values((c,), dtype, seed + 3), values((c,), dtype, seed + 4, 0.5, 2.0)] if stats else [None, None]
    theirs = [None if r is None else torch.tensor(r) for r in running]
    ours = [None if r is None else r.copy() for r in running]
    parity([x] + params, lambda x, *p: F.batch_norm(x, *theirs, *p, training=training, momentum=momentum, eps=eps),
           lambda x, *p: M.batch_norm(x, *ours, *p, training=training, momentum=momentum, eps=eps), dtype, layout, seed)
    for mine, torch_stat in zip(ours, theirs):
        if mine is not None:
            np.testing.assert_allclose(mine, torch_stat.numpy(), rtol=1e-5, atol=1e-6)


# -------------------------------------------------------------------------------------------- pools

@st.composite
def pool_cases(draw):
    k = (draw(st.integers(1, 4)), draw(st.integers(1, 4)))
    stride = draw(st.one_of(st.none(), st.tuples(st.integers(1, 3), st.integers(1, 3))))
    # torch: padding at most half the kernel
    pad = (draw(st.integers(0, k[0] // 2)), draw(st.integers(0, k[1] // 2)))
    hw = tuple(draw(st.integers(max(1, k[i] - 2 * pad[i]), 11)) for i in range(2))
    options = dict(ceil_mode=draw(st.booleans()), count_include_pad=draw(st.booleans()),
                   divisor_override=draw(st.one_of(st.none(), st.integers(1, 9))))
    return (draw(st.integers(1, 2)), draw(st.integers(1, 3))) + hw, dict(kernel_size=k, stride=stride, padding=pad, **options)


@fuzz_settings(EXAMPLES["pool"])
@given(case=pool_cases(), adaptive=st.booleans(), dtype=dtypes, layout=layouts, seed=seeds)
def test_pools(case, adaptive, dtype, layout, seed):
    shape, kw = case
    if adaptive:
        # an output size that divides the input (the sizes adaptive_avg_pool2d supports)
        out = (shape[2] // kw["kernel_size"][0] or 1, shape[3] // kw["kernel_size"][1] or 1)
        shape = shape[:2] + (out[0] * kw["kernel_size"][0], out[1] * kw["kernel_size"][1])
        parity([values(shape, dtype, seed)], lambda x: F.adaptive_avg_pool2d(x, out),
               lambda x: M.adaptive_avg_pool2d(x, out), dtype, layout, seed)
        return
    parity([values(shape, dtype, seed)], lambda x: F.avg_pool2d(x, **kw), lambda x: M.avg_pool2d(x, **kw),
           dtype, layout, seed)


# ---------------------------------------------------------------------------------------------- pad

@fuzz_settings(EXAMPLES["pad"])
@given(shape=st.one_of(spatial, st.tuples(st.integers(1, 4), st.integers(1, 7), st.integers(1, 7))),
       pads=st.lists(st.integers(0, 4), min_size=4, max_size=4), mode=st.sampled_from(["constant", "replicate"]),
       value=st.floats(-3, 3), dtype=dtypes, layout=layouts, seed=seeds)
def test_pad(shape, pads, mode, value, dtype, layout, seed):
    kw = dict(mode=mode, value=value) if mode == "constant" else dict(mode=mode)
    parity([values(shape, dtype, seed)], lambda x: F.pad(x, pads, **kw), lambda x: M.pad(x, pads, **kw),
           dtype, layout, seed)


# -------------------------------------------------------------------------------------- grid_sample

@fuzz_settings(EXAMPLES["grid_sample"])
@given(x_shape=spatial, out_hw=st.tuples(st.integers(1, 6), st.integers(1, 6)),
       padding=st.sampled_from(["zeros", "border"]), align=st.booleans(), dtype=dtypes, layout=layouts, seed=seeds)
def test_grid_sample(x_shape, out_hw, padding, align, dtype, layout, seed):
    grid = values((x_shape[0],) + out_hw + (2,), dtype, seed + 1, -1.3, 1.3)
    parity([values(x_shape, dtype, seed), grid],
           lambda x, g: F.grid_sample(x, g, padding_mode=padding, align_corners=align),
           lambda x, g: M.grid_sample(x, g, padding_mode=padding, align_corners=align), dtype, layout, seed)


# -------------------------------------------------------------------------------------- interpolate

@fuzz_settings(EXAMPLES["interpolate"])
@given(shape=spatial, size=st.one_of(st.tuples(st.integers(1, 13), st.integers(1, 13)),
                                     st.tuples(st.sampled_from([0.5, 1.5, 2.0, 3.0, 4.0]), st.sampled_from([0.5, 2.0, 2.5]))),
       align=st.booleans(), dtype=dtypes, layout=layouts, seed=seeds)
def test_interpolate_bilinear(shape, size, align, dtype, layout, seed):
    kw = dict(size=size) if isinstance(size[0], int) else dict(scale_factor=size)
    if "scale_factor" in kw and min(int(shape[2] * size[0]), int(shape[3] * size[1])) < 1:
        kw = dict(size=(max(1, int(shape[2] * size[0])), max(1, int(shape[3] * size[1]))))
    parity([values(shape, dtype, seed)], lambda x: F.interpolate(x, mode="bilinear", align_corners=align, **kw),
           lambda x: M.interpolate(x, mode="bilinear", align_corners=align, **kw), dtype, layout, seed)


# -------------------------------------------------------------------------------------- unfold/fold

@st.composite
def unfold_cases(draw):
    k, d = (draw(st.integers(1, 3)), draw(st.integers(1, 3))), (draw(st.integers(1, 2)), draw(st.integers(1, 2)))
    p, s = (draw(st.integers(0, 2)), draw(st.integers(0, 2))), (draw(st.integers(1, 2)), draw(st.integers(1, 2)))
    # the padded input must hold one dilated kernel: H + 2p >= d (k - 1) + 1
    hw = tuple(draw(st.integers(max(1, d[i] * (k[i] - 1) + 1 - 2 * p[i]), 9)) for i in range(2))
    return (draw(st.integers(1, 2)), draw(st.integers(1, 3))) + hw, dict(kernel_size=k, dilation=d, padding=p, stride=s)


@fuzz_settings(EXAMPLES["unfold_fold"])
@given(case=unfold_cases(), dtype=dtypes, layout=layouts, seed=seeds)
def test_unfold_and_fold(case, dtype, layout, seed):
    shape, geo = case
    parity([values(shape, dtype, seed)], lambda x: F.unfold(x, **geo), lambda x: M.unfold(x, **geo), dtype, layout, seed)
    cols = tuple(F.unfold(torch.zeros(shape, dtype=torch.float64), **geo).shape)
    parity([values(cols, dtype, seed + 1)], lambda c: F.fold(c, shape[2:], **geo), lambda c: M.fold(c, shape[2:], **geo),
           dtype, layout, seed)


# ------------------------------------------------------------------------------------------ softmax

@fuzz_settings(EXAMPLES["softmax"])
@given(shape=hnp.array_shapes(min_dims=1, max_dims=4, max_side=6), data=st.data(), dtype=dtypes, layout=layouts, seed=seeds)
def test_softmax(shape, data, dtype, layout, seed):
    dim = data.draw(st.integers(-len(shape), len(shape) - 1))
    parity([values(shape, dtype, seed, -8, 8)], lambda x: F.softmax(x, dim), lambda x: M.softmax(x, dim),
           dtype, layout, seed)


# -------------------------------------------------------------------------------------- elementwise

@fuzz_settings(EXAMPLES["elementwise"])
@given(shapes=hnp.mutually_broadcastable_shapes(num_shapes=2, min_dims=0, max_dims=4, max_side=5),
       op=st.sampled_from(["add", "sub", "mul", "relu", "sigmoid", "tanh", "mean", "sum", "affine"]), data=st.data(),
       dtype=dtypes, layout=layouts, seed=seeds)
def test_elementwise_broadcasting_and_reductions(shapes, op, data, dtype, layout, seed):
    a, b = shapes.input_shapes
    if op in ("add", "sub", "mul"):
        parity([values(a, dtype, seed), values(b, dtype, seed + 1)], getattr(torch, op), getattr(M, op), dtype, layout, seed)
        return
    x = values(shapes.result_shape, dtype, seed)
    if op in ("relu", "sigmoid", "tanh"):
        parity([x], getattr(torch, op), getattr(M, op), dtype, layout, seed)
    elif op == "affine":  # the scalar arithmetic of the iAFF gate: 1 - x, 0.25 * x, x + 2
        parity([x], lambda t: (1 - t) * 0.25 + 2, lambda t: (1 - t) * 0.25 + 2, dtype, layout, seed)
    else:
        ndim = len(shapes.result_shape)
        dims = data.draw(st.lists(st.integers(0, ndim - 1), unique=True, max_size=ndim)) if ndim else []
        keep = data.draw(st.booleans())
        dim = tuple(dims) if dims else None
        # torch's sum(dim=None) has no keepdim form; both reduce everything then
        torch_fn = (lambda t: getattr(torch, op)(t, dim, keepdim=keep)) if dim else getattr(torch, op)
        mipnet_fn = (lambda t: getattr(M, op)(t, dim, keepdim=keep)) if dim else getattr(M, op)
        parity([x], torch_fn, mipnet_fn, dtype, layout, seed)


# ---------------------------------------------------------------------------------------- cat/slice

@fuzz_settings(EXAMPLES["cat_slice"])
@given(shape=hnp.array_shapes(min_dims=1, max_dims=4, max_side=5), data=st.data(), dtype=dtypes, layout=layouts,
       seed=seeds)
def test_cat_and_slice(shape, data, dtype, layout, seed):
    dim = data.draw(st.integers(0, len(shape) - 1))
    sizes = data.draw(st.lists(st.integers(1, 4), min_size=1, max_size=4))
    parts = [values(shape[:dim] + (s,) + shape[dim + 1:], dtype, seed + i) for i, s in enumerate(sizes)]
    parity(parts, lambda *t: torch.cat(t, dim), lambda *t: M.cat(t, dim), dtype, layout, seed)
    start = data.draw(st.integers(0, shape[dim] - 1))
    length = data.draw(st.integers(1, shape[dim] - start))
    x = values(shape, dtype, seed)
    parity([x], lambda t: torch.narrow(t, dim, start, length), lambda t: M.narrow(t, dim, start, length),
           dtype, layout, seed)
    key = tuple(slice(data.draw(st.integers(0, s - 1)), None) for s in shape[:-1]) + (data.draw(st.integers(0, shape[-1] - 1)),)
    parity([x], lambda t: t[key], lambda t: M.index(t, key), dtype, layout, seed)


# ------------------------------------------------------------------------------------- correlations

@fuzz_settings(EXAMPLES["correlation"])
@given(n=st.integers(1, 2), groups=st.integers(1, 3), per_group=st.integers(1, 3), slots=st.just(5),
       hw=st.tuples(st.integers(1, 7), st.integers(1, 7)), kind=st.sampled_from(["ip", "rls"]),
       radius=st.tuples(st.integers(0, 3), st.integers(0, 2)), dtype=dtypes, layout=layouts, seed=seeds)
def test_ip_and_rls_correlation(n, groups, per_group, slots, hw, kind, radius, dtype, layout, seed):
    c = groups * per_group
    fl = values((n, c) + hw, dtype, seed)
    if kind == "ip":
        stack = values((n, slots * c) + hw, dtype, seed + 1)
        parity([fl, stack], lambda a, b: ip_torch(a, b, groups), lambda a, b: M.ip_correlation(a, b, groups=groups),
               dtype, layout, seed)
    else:
        rx, ry = radius
        parity([fl, values((n, c) + hw, dtype, seed + 1)], lambda a, b: rls_torch(a, b, rx, ry),
               lambda a, b: M.rls_correlation(a, b, rx=rx, ry=ry), dtype, layout, seed)


# ---------------------------------------------------------------------------------- convex upsample

@fuzz_settings(EXAMPLES["convex_upsample"])
@given(n=st.integers(1, 2), hw=st.tuples(st.integers(1, 6), st.integers(1, 6)), rate=st.integers(1, 4),
       dtype=dtypes, layout=layouts, seed=seeds)
def test_convex_upsample(n, hw, rate, dtype, layout, seed):
    flow, mask = values((n, 2) + hw, dtype, seed), values((n, 9 * rate * rate) + hw, dtype, seed + 1)
    parity([flow, mask], lambda f, m: convex_torch(f, m, rate), lambda f, m: M.convex_upsample(f, m, rate=rate),
           dtype, layout, seed)


# --------------------------------------------------------------------------------------------- loss

def _masked_l1_torch(d, gt, valid):
    v = valid > 0.5
    # invalid gt zeroed first, or abs's backward turns its NaN into NaN gradients
    return (d - torch.where(v, gt, torch.zeros_like(gt))).abs()[v].mean()


@fuzz_settings(EXAMPLES["loss"])
@given(shape=hnp.array_shapes(min_dims=2, max_dims=4, max_side=7), fraction=st.floats(0.05, 1.0),
       dtype=dtypes, layout=layouts, seed=seeds)
def test_masked_l1_loss(shape, fraction, dtype, layout, seed):
    valid = (np.random.default_rng(seed + 2).uniform(size=shape) < fraction).astype(dtype)
    valid.flat[0] = 1  # at least one valid pixel (torch's mean of nothing is NaN, mipnet's is 0)
    parity([values(shape, dtype, seed), values(shape, dtype, seed + 1), valid], _masked_l1_torch, M.masked_l1_loss,
           dtype, layout, seed, grad_inputs=[0])
