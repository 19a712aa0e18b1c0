"""conv2d against torch: forward and gradients for every kernel shape MIPNet uses, and the errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from mipnet import _core
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()
F = torch.nn.functional

# (input shape, weight shape, stride, padding): the stem, resblocks, GRUs, heads, motion encoders.
CASES = {
    "7x7_s2_p3_odd": ((2, 3, 17, 13), (8, 3, 7, 7), 2, 3),
    "5x5_p2": ((2, 2, 9, 12), (6, 2, 5, 5), 1, 2),
    "3x3_p1": ((3, 5, 11, 9), (7, 5, 3, 3), 1, 1),
    "3x3_s2_p1_odd": ((2, 4, 13, 11), (6, 4, 3, 3), 2, 1),
    "1x1": ((2, 9, 7, 10), (5, 9, 1, 1), 1, 0),
    "1x1_s2_odd": ((2, 6, 9, 11), (4, 6, 1, 1), 2, 0),
    "1x5_p0_2": ((2, 6, 5, 11), (4, 6, 1, 5), 1, (0, 2)),
    "5x1_p2_0": ((2, 6, 11, 5), (4, 6, 5, 1), 1, (2, 0)),
    "3x3_s1x2_p0x1": ((1, 3, 8, 9), (4, 3, 3, 3), (1, 2), (0, 1)),
    "3x3_tiled_48ch": ((2, 48, 45, 51), (16, 48, 3, 3), 1, 1),
}


def _inputs(xs, ws, seed=0):
    # weights scaled like a trained layer so float32 sums stay within the default tolerances
    scale = float(1.0 / np.sqrt(np.prod(ws[1:])))
    return [rand(xs, seed=seed), rand(ws, seed=seed + 1) * scale, rand(ws[:1], seed=seed + 2)]


def _winograd_tol(ws, stride, dtype):
    """Tolerances of a float32 stride-1 3x3 conv, which may run Winograd F(4x4, 3x3) (large enough
    ones do): its transforms round more than the direct sum (forward 3.2e-5 max abs at 48
    channels with Winograd forced, outputs up to ~2)."""
    winograd = dtype == np.float32 and tuple(ws[2:]) == (3, 3) and stride in (1, (1, 1))
    return dict(atol=1e-4) if winograd else {}


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("case", list(CASES))
def test_conv2d_matches_torch(case, dtype):
    xs, ws, stride, padding = CASES[case]
    check_op(_inputs(xs, ws), lambda x, w, b: F.conv2d(x, w, b, stride, padding),
             lambda x, w, b: M.conv2d(x, w, b, stride, padding), dtype=dtype, **_winograd_tol(ws, stride, dtype))


@pytest.mark.parametrize("case", ["3x3_p1", "3x3_tiled_48ch"])
def test_conv2d_direct_float32_keeps_the_default_tolerance(case, monkeypatch):
    # Winograd off: the direct convolution, within the default float32 tolerances
    from mipnet.ops import _conv

    monkeypatch.setattr(_conv, "WINOGRAD", False)
    xs, ws, stride, padding = CASES[case]
    check_op(_inputs(xs, ws), lambda x, w, b: F.conv2d(x, w, b, stride, padding),
             lambda x, w, b: M.conv2d(x, w, b, stride, padding))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_conv2d_without_bias_matches_torch(dtype):
    x, w, _ = _inputs((2, 4, 10, 9), (5, 4, 3, 3))
    check_op([x, w], lambda x, w: F.conv2d(x, w, None, 2, 1), lambda x, w: M.conv2d(x, w, stride=2, padding=1), dtype=dtype)


@pytest.mark.parametrize("stride, padding", [(1, 3), (2, 2)])
def test_1x1_conv_with_padding_has_more_output_than_input_pixels(stride, padding):
    # found by the random-shape parity test: a padded 1x1 conv is not pointwise (a 2x2 input gives 8x8 outputs)
    check_op(_inputs((1, 1, 2, 2), (3, 1, 1, 1)), lambda x, w, b: F.conv2d(x, w, b, stride, padding),
             lambda x, w, b: M.conv2d(x, w, b, stride, padding), dtype=np.float32)


def test_conv2d_detached_input_gives_weight_and_bias_grads_only():
    # the motion encoders' flow input is detached: 5x5 conv with grads to weight and bias only
    check_op(_inputs((2, 2, 12, 16), (8, 2, 5, 5)), lambda x, w, b: F.conv2d(x, w, b, padding=2),
             lambda x, w, b: M.conv2d(x, w, b, padding=2), grad_inputs=[1, 2])


def test_conv2d_non_contiguous_inputs_match_torch():
    x, w, b = _inputs((2, 3, 9, 7), (4, 3, 3, 3))
    ref = F.conv2d(torch.tensor(x), torch.tensor(w), torch.tensor(b), 2, 1).numpy()
    # through the Tensor wrapper and straight into the kernel (which normalises the layout itself)
    out = M.conv2d(mipnet.tensor(non_contiguous(x)), mipnet.tensor(non_contiguous(w)), b, 2, 1).numpy()
    np.testing.assert_allclose(out, ref, rtol=1e-5, atol=1e-5)
    raw = _core.conv2d_fwd(non_contiguous(x), non_contiguous(w), b[::-1].copy()[::-1], (2, 2), (1, 1))
    np.testing.assert_allclose(raw, ref, rtol=1e-5, atol=1e-5)
    g = rand(ref.shape, seed=9)
    dx, dw, db = _core.conv2d_bwd(non_contiguous(x), non_contiguous(w), non_contiguous(g), (2, 2), (1, 1))
    xt, wt = torch.tensor(x, requires_grad=True), torch.tensor(w, requires_grad=True)
    bt = torch.tensor(b, requires_grad=True)
    F.conv2d(xt, wt, bt, 2, 1).backward(torch.tensor(g))
    for ours, theirs in ((dx, xt.grad), (dw, wt.grad), (db, bt.grad)):
        np.testing.assert_allclose(ours, theirs.numpy(), rtol=1e-4, atol=1e-4)


def test_conv2d_accepts_numpy_arrays_and_valid_padding():
    x, w, b = _inputs((1, 2, 6, 7), (3, 2, 3, 3))
    ref = F.conv2d(torch.tensor(x), torch.tensor(w), torch.tensor(b)).numpy()
    np.testing.assert_allclose(M.conv2d(x, w, b, padding="valid").numpy(), ref, rtol=1e-5, atol=1e-5)


def test_conv2d_bwd_skips_grads_not_requested():
    x, w, _ = _inputs((1, 2, 6, 7), (3, 2, 3, 3))
    g = rand((1, 3, 6, 7), seed=3)
    dx, dw, db = _core.conv2d_bwd(x, w, g, (1, 1), (1, 1), need_x=False, need_w=True, need_b=False)
    assert dx is None and db is None and dw.shape == w.shape


def test_inference_conv2d_keeps_winograd_kernels_only_while_the_weights_stay_the_same():
    # a no-grad pass keeps the transformed kernels of its Winograd convolutions (found again by the
    # weight values): same result as a recorded pass, and an in-place weight update is not missed
    x, w, b = _inputs((1, 32, 96, 96), (32, 32, 3, 3))
    with mipnet.no_grad():
        kept = [M.conv2d(x, w, b, padding=1).numpy() for _ in range(2)]
    recorded = M.conv2d(mipnet.tensor(x, requires_grad=True), w, b, padding=1).detach().numpy()
    np.testing.assert_array_equal(kept[0], recorded)
    np.testing.assert_array_equal(kept[1], recorded)
    w[:, :, 1, 1] += 0.5
    with mipnet.no_grad():
        updated = M.conv2d(x, w, b, padding=1).numpy()
    ref = F.conv2d(torch.tensor(x), torch.tensor(w), torch.tensor(b), padding=1).numpy()
    np.testing.assert_allclose(updated, ref, rtol=1e-4, atol=1e-4)
    assert np.abs(updated - kept[0]).max() > 0.1


def _raises(match, fn, exc=RuntimeError):
    with pytest.raises(exc, match=match):
        fn()


@pytest.mark.parametrize("xs,ws,bs,stride,padding,match", [
    ((2, 3, 8, 8), (4, 5, 3, 3), None, 1, 1, r"conv2d.*weight\.shape\[1\].*\[2, 3, 8, 8\].*\[4, 5, 3, 3\]"),
    ((3, 8, 8), (4, 3, 3, 3), None, 1, 1, r"conv2d: input must be a 4-D tensor.*\[3, 8, 8\]"),
    ((2, 3, 8, 8), (4, 3, 3), None, 1, 1, r"conv2d: weight must be a 4-D tensor.*\[4, 3, 3\]"),
    ((2, 3, 8, 8), (4, 3, 3, 3), (5,), 1, 1, r"conv2d: bias.*\[4, 3, 3, 3\].*\[5\]"),
    ((1, 3, 4, 9), (2, 3, 7, 7), None, 1, 1, r"conv2d: the kernel .* padded input.*\[1, 3, 4, 9\].*\[2, 3, 7, 7\]"),
    ((0, 3, 8, 8), (4, 3, 3, 3), None, 1, 1, r"conv2d: empty.*\[0, 3, 8, 8\]"),
    ((2, 3, 8, 8), (4, 3, 0, 3), None, 1, 1, r"conv2d: empty.*\[4, 3, 0, 3\]"),
    ((2, 3, 8, 8), (4, 3, 3, 3), None, 0, 1, r"conv2d: stride must be at least 1.*\[0, 0\]"),
    ((2, 3, 8, 8), (4, 3, 3, 3), None, 1, -1, r"conv2d: padding must be non-negative"),
])
def test_conv2d_rejects_bad_shapes_and_arguments(xs, ws, bs, stride, padding, match):
    b = None if bs is None else np.zeros(bs, np.float32)
    _raises(match, lambda: M.conv2d(np.zeros(xs, np.float32), np.zeros(ws, np.float32), b, stride, padding))


def test_conv2d_rejects_unsupported_torch_arguments():
    x, w, _ = _inputs((1, 2, 6, 7), (3, 2, 3, 3))
    _raises(r"conv2d: only dilation=1", lambda: M.conv2d(x, w, dilation=2), mipnet.errors.ArgumentError)
    _raises(r"conv2d: only groups=1", lambda: M.conv2d(x, w, groups=2), mipnet.errors.ArgumentError)
    _raises(r"conv2d: padding must be .* 'same'", lambda: M.conv2d(x, w, padding="same"), mipnet.errors.ArgumentError)
    _raises(r"conv2d: stride must be an int or a pair", lambda: M.conv2d(x, w, stride=(1, 2, 3)), mipnet.errors.ArgumentError)


def test_conv2d_rejects_wrong_and_mixed_dtypes():
    x, w, b = _inputs((1, 2, 6, 7), (3, 2, 3, 3))
    _raises(r"conv2d: inputs must share one dtype", lambda: M.conv2d(x, w.astype(np.float64), b), mipnet.errors.DTypeError)
    _raises(r"conv2d: input must be a float32 or float64", lambda: _core.conv2d_fwd(x.astype(np.int32), w),
            mipnet.errors.DTypeError)
    _raises(r"conv2d: bias must be a float32", lambda: _core.conv2d_fwd(x, w, b.astype(np.float64)), mipnet.errors.DTypeError)
    _raises(r"tensor: dtype must be float32 or float64", lambda: M.conv2d(x.astype(np.int64), w), mipnet.errors.DTypeError)


def test_conv2d_bwd_rejects_grad_output_of_the_wrong_shape():
    x, w, _ = _inputs((1, 2, 6, 7), (3, 2, 3, 3))
    _raises(r"conv2d: grad_output must have shape \[1, 3, 6, 7\].*grad_output=\[1, 3, 6, 6\]",
            lambda: _core.conv2d_bwd(x, w, np.zeros((1, 3, 6, 6), np.float32), (1, 1), (1, 1)))


def test_gemm_fwd_matches_numpy_and_checks_shapes():
    a, b = rand((70, 33)), rand((33, 90), seed=1)
    np.testing.assert_allclose(_core.gemm_fwd(a, b), a @ b, rtol=1e-5, atol=1e-5)
    _raises(r"gemm: a\.shape\[1\] must equal b\.shape\[0\].*\[70, 33\].*\[34, 90\]", lambda: _core.gemm_fwd(a, rand((34, 90))))
    # large enough for both threads (A packed once for both column blocks), wide and tall
    for m, k, n in [(150, 300, 700), (700, 300, 150)]:
        a, b = rand((m, k)), rand((k, n), seed=2)
        np.testing.assert_allclose(_core.gemm_fwd(a, b), a.astype(np.float64) @ b, rtol=1e-4, atol=1e-4)
    # an output too large to allocate is an error naming the op and the shape, not an abort
    one = np.float32(1)
    _raises(r"gemm: the output is too large to allocate.*\[1048576, 1099511627776\]",
            lambda: _core.gemm_fwd(np.broadcast_to(one, (1 << 20, 1)), np.broadcast_to(one, (1, 1 << 40))))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("case", ["3x3_p1", "1x1", "7x7_s2_p3_odd", "1x5_p0_2"])
def test_conv2d_relu_matches_torch_and_the_two_ops(case, dtype):
    xs, ws, stride, padding = CASES[case]
    inputs = _inputs(xs, ws)
    check_op(inputs, lambda x, w, b: F.relu(F.conv2d(x, w, b, stride, padding)),
             lambda x, w, b: M.conv2d_relu(x, w, b, stride, padding), dtype=dtype, **_winograd_tol(ws, stride, dtype))
    x, w, b = (a.astype(dtype) for a in inputs)
    # the epilogue's ReLU is the relu op on the same sums: bitwise equal
    np.testing.assert_array_equal(M.conv2d_relu(x, w, b, stride, padding).numpy(),
                                  M.relu(M.conv2d(x, w, b, stride, padding)).numpy())


# Run in a subprocess with MIPNET_ISA set: float32 conv2d forward and gradients (and a GEMM) on the
# forced path against torch in float64. Prints the path the process used.
_FORCED_ISA_SCRIPT = r"""
import numpy as np, torch
import mipnet, mipnet.ops as M
from mipnet import _core
F = torch.nn.functional
rng = np.random.default_rng(0)
print(_core.cpu_info()["isa"])
worst = 0.0
for xs, ws, stride, pad in [((2, 16, 13, 11), (24, 16, 3, 3), 1, 1), ((1, 3, 17, 15), (8, 3, 7, 7), 2, 3),
                            ((2, 9, 7, 10), (5, 9, 1, 1), 1, 0), ((2, 6, 5, 11), (4, 6, 1, 5), 1, (0, 2))]:
    x = rng.standard_normal(xs).astype(np.float32)
    w = (rng.standard_normal(ws) / np.sqrt(np.prod(ws[1:]))).astype(np.float32)
    b = rng.standard_normal(ws[:1]).astype(np.float32)
    ts = [torch.tensor(a, dtype=torch.float64, requires_grad=True) for a in (x, w, b)]
    ref = F.conv2d(*ts, stride=stride, padding=pad)
    g = rng.uniform(-1, 1, ref.shape)
    ref.backward(torch.tensor(g))
    ms = [mipnet.tensor(a, requires_grad=True) for a in (x, w, b)]
    out = M.conv2d(*ms, stride=stride, padding=pad)
    out.backward(g.astype(np.float32))
    for ours, theirs in [(out, ref)] + [(m.grad, t.grad) for m, t in zip(ms, ts)]:
        err = np.abs(ours.numpy().astype(np.float64) - theirs.detach().numpy()).max()
        scale = 1.0 + np.abs(theirs.detach().numpy()).max()
        worst = max(worst, err / scale)
a = rng.standard_normal((67, 301)).astype(np.float32)
c = rng.standard_normal((301, 53)).astype(np.float32)
worst = max(worst, np.abs(_core.gemm_fwd(a, c) - a.astype(np.float64) @ c).max() / 30.0)
print(worst)
"""


def _run_forced(isa: str):
    import os
    import subprocess
    import sys

    env = {**os.environ, "MIPNET_ISA": isa}
    return subprocess.run([sys.executable, "-c", _FORCED_ISA_SCRIPT], env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("isa", ["avx2", "generic"])
def test_forced_isa_path_matches_float64_reference(isa):
    # CI forces each non-default path once through MIPNET_ISA and checks it against float64
    if isa not in _core.cpu_info()["isa_supported"]:
        pytest.skip(f"this CPU has no {isa}")
    res = _run_forced(isa)
    assert res.returncode == 0, res.stderr
    used, worst = res.stdout.split()
    assert used == isa
    assert float(worst) < 1e-5, f"{isa}: relative error {worst}"


def test_invalid_forced_isa_is_refused_by_the_first_kernel_call():
    res = _run_forced("avx1024")
    assert res.returncode != 0
    assert "ArgumentError" in res.stderr and "MIPNET_ISA" in res.stderr and "avx512, avx2, generic" in res.stderr
