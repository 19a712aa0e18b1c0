"""``mipnet.autocast(dtype="bfloat16")``: convolutions with bfloat16 products and float32 sums, against exact
products of the rounded operands and against ``torch.autocast("cpu", dtype=torch.bfloat16)``; the model's
disparity; the float32 fallback on a CPU (or ISA path) without bf16 dot products."""

import os
import subprocess
import sys
import threading

import numpy as np
import pytest

import mipnet
from mipnet import _core
from mipnet.errors import ArgumentError
from helpers import require_torch

torch = require_torch()
F = torch.nn.functional

needs_bf16 = pytest.mark.skipif(not _core.bf16_supported(),
                                reason="this CPU has no AVX512_BF16: test_autocast_falls_back_to_float32_and_says_so_once "
                                       "covers it")


def round_to_bf16(x: np.ndarray) -> np.ndarray:
    """float32 values rounded to bfloat16 (nearest, ties to even), as float32."""
    bits = np.ascontiguousarray(x, dtype=np.float32).view(np.uint32).astype(np.uint64)
    rounded = ((bits + 0x7FFF + ((bits >> 16) & 1)) >> 16) << 16
    return rounded.astype(np.uint32).view(np.float32)


def conv_case(n, cin, cout, h, w, k, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, cin, h, w)).astype(np.float32)
    weight = (rng.standard_normal((cout, cin, k, k)) / np.sqrt(cin * k * k)).astype(np.float32)
    bias = rng.standard_normal(cout).astype(np.float32)
    return x, weight, bias


def conv(x, weight, bias, padding):
    return mipnet.ops.conv2d(mipnet.Tensor(x), mipnet.Tensor(weight), mipnet.Tensor(bias), padding=padding).numpy()


@needs_bf16
@pytest.mark.parametrize("k,padding", [(3, 1), (1, 0), (7, 3)])
def test_direct_conv_is_the_float32_sum_of_bf16_rounded_products(k, padding):
    """Small maps (the direct, im2col path): the exact convolution of the rounded input and weights (bias in
    float32), to float32 summation error: |error| <= 1e-5 · Σ|terms|."""
    x, weight, bias = conv_case(2, 24, 40, 13, 17, k)
    with mipnet.autocast(dtype="bfloat16"):
        got = conv(x, weight, bias, padding)
    xr, wr = (torch.tensor(round_to_bf16(a), dtype=torch.float64) for a in (x, weight))
    exact = F.conv2d(xr, wr, torch.tensor(bias, dtype=torch.float64), padding=padding).numpy()
    scale = F.conv2d(xr.abs(), wr.abs(), padding=padding).numpy()
    assert np.all(np.abs(got - exact) <= 1e-5 * scale + 1e-6)
    assert np.abs(got - conv(x, weight, bias, padding)).max() > 0  # the products were rounded


@needs_bf16
def test_direct_conv_matches_torch_autocast():
    """Against torch's CPU autocast, whose output is itself rounded to bfloat16 (ours stays float32): within
    2^-8 of |output| + Σ|terms|, one bf16 rounding of each."""
    x, weight, bias = conv_case(2, 24, 40, 13, 17, 3)
    with mipnet.autocast(dtype="bfloat16"):
        got = conv(x, weight, bias, 1)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        theirs = F.conv2d(torch.tensor(x), torch.tensor(weight), torch.tensor(bias), padding=1)
    assert theirs.dtype == torch.bfloat16
    theirs = theirs.float().numpy()
    scale = F.conv2d(torch.tensor(np.abs(x)), torch.tensor(np.abs(weight)), padding=1).numpy()
    assert np.all(np.abs(got - theirs) <= 2.0 ** -8 * (np.abs(theirs) + scale))


@needs_bf16
@pytest.mark.parametrize("n, cin, cout, h, w, kernel", [(4, 64, 64, 48, 64, (3, 3)), (1, 33, 40, 44, 52, (3, 3)),
                                                        (2, 37, 40, 20, 36, (1, 5)), (2, 37, 40, 36, 20, (5, 1))],
                         ids=["3x3", "3x3-odd-channels-and-tiles", "1x5-odd-channels", "5x1-odd-channels"])
def test_winograd_conv_error_is_stated(n, cin, cout, h, w, kernel):
    """A convolution large enough for Winograd (F(4x4, 3x3), F(4, 5)) rounds its transformed operands to bf16,
    which the transforms write as pairs of input channels (an odd channel count leaves the last pair half
    empty): not its inputs. 3x3 64->64 measured against float32: mean error 1.0e-3 and largest 3.8e-2 of
    Σ|terms| (torch's autocast, direct: 1.5e-4 and 1.1e-3). The bounds keep that, with room for another CPU's
    rounding of the same sums."""
    rng = np.random.default_rng(0)
    x = rng.standard_normal((n, cin, h, w)).astype(np.float32)
    weight = (rng.standard_normal((cout, cin, *kernel)) / np.sqrt(cin * kernel[0] * kernel[1])).astype(np.float32)
    bias = rng.standard_normal(cout).astype(np.float32)
    padding = (kernel[0] // 2, kernel[1] // 2)
    with mipnet.autocast(dtype="bfloat16"):
        got = conv(x, weight, bias, padding)
    full = F.conv2d(torch.tensor(x), torch.tensor(weight), torch.tensor(bias), padding=padding).numpy()
    relative = np.abs(got - full) / F.conv2d(torch.tensor(np.abs(x)), torch.tensor(np.abs(weight)), padding=padding).numpy()
    print(f"\n[bf16] Winograd {kernel} {cin}->{cout}: error / Σ|terms| mean {relative.mean():.2e}, max {relative.max():.2e}")
    assert relative.mean() <= 2e-3 and relative.max() <= 8e-2


@needs_bf16
def test_model_disparity_is_within_a_tenth_of_a_pixel_of_float32():
    left, right = mipnet.data.example_pair()["left"], mipnet.data.example_pair()["right"]
    model = mipnet.MIPNet.pretrained()
    full = model(left, right)
    with mipnet.autocast(dtype="bfloat16"):
        half = model(left, right)
    assert half.dtype == np.float32
    difference = float(np.abs(half - full).mean())
    print(f"\n[bf16] bundled pair: mean |bf16 - fp32| = {difference:.4f} px")
    assert 0 < difference <= 0.1


def test_autocast_is_scoped_to_its_thread_and_block():
    x, weight, bias = conv_case(1, 8, 8, 9, 9, 3)
    before = conv(x, weight, bias, 1)
    seen = []
    with mipnet.autocast(dtype="bfloat16"):
        with mipnet.autocast(dtype="bfloat16", enabled=False):
            seen.append(mipnet.amp.bf16_active())
        seen.append(mipnet.amp.bf16_active())
        other = threading.Thread(target=lambda: seen.append(mipnet.amp.bf16_active()))
        other.start()
        other.join()
    assert seen == [_core.bf16_supported(), _core.bf16_supported(), False]
    assert not mipnet.amp.bf16_active()
    np.testing.assert_array_equal(conv(x, weight, bias, 1), before)


def test_autocast_rejects_other_types_and_devices():
    with pytest.raises(ArgumentError, match="dtype must be 'bfloat16'"):
        mipnet.autocast(dtype="float16")
    with pytest.raises(ArgumentError, match="device_type must be 'cpu'"):
        mipnet.autocast("cuda")
    assert mipnet.autocast("cpu", dtype="torch.bfloat16").enabled


def test_autocast_falls_back_to_float32_and_says_so_once():
    """On the portable path (as on a CPU without AVX512_BF16): one warning for two contexts, float32 results bit for bit."""
    script = (
        "import warnings, numpy as np, mipnet\n"
        "x = np.random.default_rng(0).standard_normal((1, 16, 20, 20)).astype(np.float32)\n"
        "w = np.random.default_rng(1).standard_normal((16, 16, 3, 3)).astype(np.float32)\n"
        "run = lambda: mipnet.ops.conv2d(mipnet.Tensor(x), mipnet.Tensor(w), padding=1).numpy()\n"
        "plain = run()\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always')\n"
        "    with mipnet.autocast(dtype='bfloat16'):\n"
        "        first = run()\n"
        "    with mipnet.autocast(dtype='bfloat16'):\n"
        "        second = run()\n"
        "assert not mipnet._core.bf16_supported()\n"
        "assert [str(c.message) for c in caught] == [str(caught[0].message)], caught\n"
        "assert 'no bfloat16 dot products on the generic path' in str(caught[0].message)\n"
        "assert (first == plain).all() and (second == plain).all()\n"
        "print('ok')\n"
    )
    env = {**os.environ, "MIPNET_ISA": "generic"}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr
