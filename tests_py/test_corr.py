"""IP and RLS correlations against their PyTorch formulations (architecture.md §2.5, §2.6), forward and backward."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()
from reference import rls_correlation as reference_rls  # noqa: E402


def ip_torch(fl, stack, groups=2):
    n, c, h, w = fl.shape
    s = stack.shape[1] // c
    return (stack.view(n, s, groups, c // groups, h, w) * fl.view(n, 1, groups, c // groups, h, w)).mean(3) \
        .permute(0, 2, 1, 3, 4).reshape(n, groups * s, h, w)


def rls_torch(fl, warped, rx=3, ry=1):
    """The literal pad/slice/mean loop (architecture.md §2.6), as the reference model computes it."""
    return reference_rls(fl, warped, rx, ry)


def test_ip_torch_reference_is_channel_s_times_g_plus_s():
    # the torch expression equals the definition: out[S*g + s] = mean_k fl[g*C/G + k] * stack[s*C + g*C/G + k]
    n, c, s, g, h, w = 1, 8, 5, 2, 3, 4
    fl, st = rand((n, c, h, w), np.float64), rand((n, s * c, h, w), np.float64, seed=1)
    ref = ip_torch(torch.tensor(fl), torch.tensor(st), g).numpy()
    cg = c // g
    for gi in range(g):
        for si in range(s):
            want = np.mean([fl[:, gi * cg + k] * st[:, si * c + gi * cg + k] for k in range(cg)], axis=0)
            np.testing.assert_allclose(ref[:, s * gi + si], want, rtol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n,c,s,g,h,w", [(2, 8, 5, 2, 5, 7), (1, 16, 5, 2, 3, 4), (1, 6, 3, 3, 1, 9), (2, 4, 1, 1, 2, 3)])
def test_ip_correlation_matches_torch(n, c, s, g, h, w, dtype):
    check_op([rand((n, c, h, w)), rand((n, s * c, h, w), seed=2)], lambda a, b: ip_torch(a, b, g),
             lambda a, b: M.ip_correlation(a, b, groups=g), dtype=dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n,c,h,w,rx,ry", [(2, 8, 5, 9, 3, 1), (1, 16, 3, 2, 3, 1), (1, 5, 1, 1, 3, 1), (1, 8, 7, 6, 2, 0),
                                           (1, 3, 4, 5, 0, 2)])
def test_rls_correlation_matches_torch(n, c, h, w, rx, ry, dtype):
    check_op([rand((n, c, h, w)), rand((n, c, h, w), seed=2)], lambda a, b: rls_torch(a, b, rx, ry),
             lambda a, b: M.rls_correlation(a, b, rx=rx, ry=ry), dtype=dtype)


def test_correlations_non_contiguous_inputs():
    fl, st, wp = rand((1, 8, 4, 5)), rand((1, 40, 4, 5), seed=1), rand((1, 8, 4, 5), seed=2)
    t = lambda a: torch.tensor(np.ascontiguousarray(a))
    m = lambda a: mipnet.tensor(non_contiguous(a))
    np.testing.assert_allclose(M.ip_correlation(m(fl), m(st)).numpy(), ip_torch(t(fl), t(st)).numpy(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(M.rls_correlation(m(fl), m(wp)).numpy(), rls_torch(t(fl), t(wp)).numpy(), rtol=1e-5, atol=1e-6)


def test_correlation_errors_name_op_and_shapes():
    fl = mipnet.tensor(rand((1, 8, 3, 4)))
    with pytest.raises(RuntimeError, match=r"ip_correlation.*\[1, 8, 3, 4\].*\[1, 36, 3, 4\]"):
        M.ip_correlation(fl, mipnet.tensor(rand((1, 36, 3, 4))))
    with pytest.raises(RuntimeError, match=r"ip_correlation.*groups=3.*\[1, 8, 3, 4\]"):
        M.ip_correlation(fl, mipnet.tensor(rand((1, 40, 3, 4))), groups=3)
    with pytest.raises(mipnet.errors.ArgumentError, match="ip_correlation.*groups"):
        M.ip_correlation(fl, mipnet.tensor(rand((1, 40, 3, 4))), groups=0)
    with pytest.raises(RuntimeError, match=r"ip_correlation.*4-D.*\[8, 3, 4\]"):
        M.ip_correlation(mipnet.tensor(rand((8, 3, 4))), mipnet.tensor(rand((1, 40, 3, 4))))
    with pytest.raises(RuntimeError, match=r"rls_correlation.*\[1, 8, 3, 4\].*\[1, 8, 4, 4\]"):
        M.rls_correlation(fl, mipnet.tensor(rand((1, 8, 4, 4))))
    with pytest.raises(mipnet.errors.ArgumentError, match="rls_correlation.*rx"):
        M.rls_correlation(fl, fl, rx=-1)
    with pytest.raises(RuntimeError, match=r"rls_correlation.*empty.*\[1, 8, 0, 4\]"):
        z = mipnet.tensor(np.zeros((1, 8, 0, 4), np.float32))
        M.rls_correlation(z, z)
    with pytest.raises(mipnet.errors.DTypeError, match=r"rls_correlation.*float32\[1, 8, 3, 4\].*float64"):
        M.rls_correlation(fl, mipnet.tensor(rand((1, 8, 3, 4), np.float64)))


def test_correlations_at_model_channel_counts_float32():
    # the model's widths (C = 256, S = 5, G = 2; 21 RLS candidates) at a small 1/16-level size
    fl, st, wp = rand((1, 256, 6, 8)), rand((1, 1280, 6, 8), seed=1), rand((1, 256, 6, 8), seed=2)
    check_op([fl, st], ip_torch, lambda a, b: M.ip_correlation(a, b))
    check_op([fl, wp], rls_torch, lambda a, b: M.rls_correlation(a, b))


# ---- fused warp + correlation (vertical flow zero), against grid_sample of the reference model ----

from reference import build_ip_stack, warp  # noqa: E402


def _flow_x(n, h, w, seed=3):
    # f_x in [-(w+1), 2]: samples beyond both borders too (border clamping)
    return np.random.default_rng(seed).uniform(-(w + 1), 2, size=(n, h, w))


def _channels_last(t):
    return t.permute(0, 3, 1, 2)  # torch side: (N, h, w, C) input -> (N, C, h, w)


def _torch_flow(fx, like):
    fx = torch.tensor(fx, dtype=like.dtype)
    return torch.stack([fx, torch.zeros_like(fx)], 1)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n,c,g,h,w", [(2, 8, 2, 5, 7), (1, 16, 2, 1, 9), (1, 6, 3, 4, 1), (1, 256, 2, 6, 8)])
def test_ip_warp_correlation_matches_grid_sample_of_the_seed_stack(n, c, g, h, w, dtype):
    fx = _flow_x(n, h, w)
    check_op([rand((n, h, w, c)), rand((n, h, w, c), seed=2)],
             lambda a, b: ip_torch(_channels_last(a), warp(build_ip_stack(_channels_last(b)), _torch_flow(fx, a)), g),
             lambda a, b: M.ip_warp_correlation(a, b, fx, groups=g), dtype=dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n,c,h,w,rx,ry", [(2, 8, 5, 9, 3, 1), (1, 16, 3, 2, 3, 1), (1, 5, 1, 1, 3, 1), (1, 8, 7, 6, 2, 0),
                                           (1, 3, 4, 5, 0, 2), (1, 256, 6, 8, 3, 1)])
def test_rls_warp_correlation_matches_grid_sample_then_rls(n, c, h, w, rx, ry, dtype):
    fx = _flow_x(n, h, w)
    check_op([rand((n, h, w, c)), rand((n, h, w, c), seed=2)],
             lambda a, b: rls_torch(_channels_last(a), warp(_channels_last(b), _torch_flow(fx, a)), rx, ry),
             lambda a, b: M.rls_warp_correlation(a, b, fx, rx=rx, ry=ry), dtype=dtype)


def test_warp_correlation_errors_name_op_and_shapes():
    fl = mipnet.tensor(rand((1, 3, 4, 8)))
    with pytest.raises(RuntimeError, match=r"ip_warp_correlation.*\[1, 3, 4, 8\].*\[1, 3, 5, 8\]"):
        M.ip_warp_correlation(fl, mipnet.tensor(rand((1, 3, 5, 8))), np.zeros((1, 3, 4)))
    with pytest.raises(RuntimeError, match=r"rls_warp_correlation.*flow_x=\[1, 4, 3\]"):
        M.rls_warp_correlation(fl, fl, np.zeros((1, 4, 3)))
    with pytest.raises(mipnet.errors.InvalidValueError, match="ip_warp_correlation.*NaN"):
        M.ip_warp_correlation(fl, fl, np.full((1, 3, 4), np.nan))
    with pytest.raises(mipnet.errors.ArgumentError, match="rls_warp_correlation.*rx"):
        M.rls_warp_correlation(fl, fl, np.zeros((1, 3, 4)), rx=-1)
