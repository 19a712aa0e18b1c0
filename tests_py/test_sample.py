"""grid_sample, interpolate (bilinear), unfold and fold against torch, forward and backward, and errors."""

import numpy as np
import pytest

import mipnet
import mipnet.ops as M
from helpers import check_op, non_contiguous, rand, require_torch

torch = require_torch()
F = torch.nn.functional

# ---- grid_sample ---------------------------------------------------------------------------------

GS_SHAPES = [((2, 3, 9, 11), (2, 5, 7, 2)), ((1, 4, 6, 5), (1, 8, 3, 2)), ((3, 2, 1, 7), (3, 2, 4, 2))]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("align", [True, False])
@pytest.mark.parametrize("padding", ["zeros", "border"])
@pytest.mark.parametrize("xs,gs", GS_SHAPES)
def test_grid_sample_matches_torch_beyond_the_borders(padding, align, dtype, xs, gs):
    # grid values reach 1.4 outside [-1, 1], so both padding modes and the border clamp are exercised
    check_op([rand(xs), rand(gs, low=-1.4, high=1.4, seed=3)],
             lambda x, g: F.grid_sample(x, g, padding_mode=padding, align_corners=align),
             lambda x, g: M.grid_sample(x, g, padding_mode=padding, align_corners=align), dtype=dtype)


@pytest.mark.parametrize("padding", ["zeros", "border"])
@pytest.mark.parametrize("align", [True, False])
def test_grid_sample_on_pixel_centres_and_exact_borders_matches_torch(padding, align):
    # integer sample positions and points exactly on / beyond the border: torch treats the border as
    # outside for the grid gradient (it is 0 there in border mode); we must agree exactly
    h, w = 4, 6
    xs = np.arange(-2, w + 2) if align else np.arange(-2, w + 2) + 0.5
    ys = np.arange(-1, h + 1) if align else np.arange(-1, h + 1) + 0.5
    gx = 2 * xs / (w - 1) - 1 if align else 2 * xs / w - 1
    gy = 2 * ys / (h - 1) - 1 if align else 2 * ys / h - 1
    grid = np.stack(np.meshgrid(gx, gy, indexing="xy"), -1)[None]
    grid = np.concatenate([grid, np.array([[[[-1.0, 1.0], [1.0, -1.0]]]]).repeat(grid.shape[1], 1)], 2)
    check_op([rand((1, 3, h, w)), grid], lambda x, g: F.grid_sample(x, g, padding_mode=padding, align_corners=align),
             lambda x, g: M.grid_sample(x, g, padding_mode=padding, align_corners=align), dtype=np.float64)


def _warp(ops, feat, flow):
    """The warp W(F, f) (architecture.md §2.3) written with either library's grid_sample."""
    n, _, h, w = flow.shape
    xs = np.arange(w, dtype=flow.dtype)[None, :] + flow[:, 0]
    ys = np.arange(h, dtype=flow.dtype)[:, None] + flow[:, 1]
    grid = np.stack([2 * xs / max(w - 1, 1) - 1, 2 * ys / max(h - 1, 1) - 1], -1)
    return ops(feat, grid)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_grid_sample_horizontal_warp_matches_torch(dtype):
    flow = np.stack([-rand((2, 7, 13), dtype, 0, 9, seed=5), np.zeros((2, 7, 13), dtype)], 1)
    gs_t = lambda x, g: F.grid_sample(x, g, mode="bilinear", padding_mode="border", align_corners=True)
    gs_m = lambda x, g: M.grid_sample(x, g, mode="bilinear", padding_mode="border", align_corners=True)
    grid_of = lambda: _warp(lambda f, g: g, None, flow)
    # the model's warp: the grid is detached, only the features get a gradient
    check_op([rand((2, 16, 7, 13)), grid_of()], gs_t, gs_m, grad_inputs=[0], dtype=dtype)


def test_grid_sample_non_contiguous_inputs_and_default_align():
    x, g = rand((2, 3, 5, 6)), rand((2, 4, 3, 2), low=-1.2, high=1.2, seed=9)
    ours = M.grid_sample(mipnet.tensor(non_contiguous(x)), mipnet.tensor(non_contiguous(g)), padding_mode="border").numpy()
    theirs = F.grid_sample(torch.tensor(x), torch.tensor(g), padding_mode="border", align_corners=False).numpy()
    np.testing.assert_allclose(ours, theirs, rtol=1e-5, atol=1e-6)


def test_grid_sample_errors_name_op_and_shapes():
    x, g = mipnet.tensor(rand((2, 3, 4, 5))), rand((2, 6, 7, 2))
    bad = g.copy()
    bad[1, 2, 3, 0] = np.nan
    with pytest.raises(mipnet.errors.InvalidValueError, match=r"grid_sample.*NaN.*\[2, 6, 7, 2\]"):
        M.grid_sample(x, mipnet.tensor(bad))
    with pytest.raises(mipnet.errors.ArgumentError, match="grid_sample.*nearest"):
        M.grid_sample(x, mipnet.tensor(g), mode="nearest")
    with pytest.raises(mipnet.errors.ArgumentError, match="grid_sample.*reflection"):
        M.grid_sample(x, mipnet.tensor(g), padding_mode="reflection")
    with pytest.raises(RuntimeError, match=r"grid_sample.*\[2, 3, 4, 5\].*\[2, 6, 7, 3\]"):
        M.grid_sample(x, mipnet.tensor(rand((2, 6, 7, 3))))
    with pytest.raises(RuntimeError, match=r"grid_sample.*\[2, 3, 4, 5\].*\[3, 6, 7, 2\]"):
        M.grid_sample(x, mipnet.tensor(rand((3, 6, 7, 2))))
    with pytest.raises(RuntimeError, match=r"grid_sample.*4-D.*\[6, 7, 2\]"):
        M.grid_sample(x, mipnet.tensor(rand((6, 7, 2))))
    with pytest.raises(RuntimeError, match=r"grid_sample.*empty.*\[2, 3, 0, 5\]"):
        M.grid_sample(mipnet.tensor(np.zeros((2, 3, 0, 5), np.float32)), mipnet.tensor(g))
    with pytest.raises(mipnet.errors.DTypeError, match=r"grid_sample.*float32\[2, 3, 4, 5\].*float64"):
        M.grid_sample(x, mipnet.tensor(g.astype(np.float64)))


# ---- interpolate ---------------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("align", [True, False])
@pytest.mark.parametrize("kw", [dict(size=(20, 28)), dict(size=(3, 4)), dict(size=7), dict(scale_factor=1.7),
                                dict(scale_factor=(2.0, 0.5)), dict(scale_factor=1.3, recompute_scale_factor=True)])
def test_interpolate_bilinear_matches_torch(align, kw, dtype):
    check_op([rand((2, 2, 5, 7))], lambda x: F.interpolate(x, mode="bilinear", align_corners=align, **kw),
             lambda x: M.interpolate(x, mode="bilinear", align_corners=align, **kw), dtype=dtype)


def test_interpolate_spec_bilinear_up4_and_default_align():
    # architecture.md §2.8: 4 * F.interpolate(f, size=(4h, 4w), mode='bilinear', align_corners=True)
    check_op([rand((1, 2, 6, 9))], lambda f: 4 * F.interpolate(f, size=(24, 36), mode="bilinear", align_corners=True),
             lambda f: 4 * M.interpolate(f, size=(24, 36), mode="bilinear", align_corners=True))
    check_op([rand((1, 2, 6, 9))], lambda f: F.interpolate(f, size=(5, 13), mode="bilinear"),
             lambda f: M.interpolate(f, size=(5, 13), mode="bilinear"))


def test_interpolate_errors():
    x = mipnet.tensor(rand((1, 2, 3, 4)))
    with pytest.raises(mipnet.errors.ArgumentError, match="interpolate.*nearest"):
        M.interpolate(x, size=(6, 8))
    with pytest.raises(mipnet.errors.ArgumentError, match="interpolate.*exactly one"):
        M.interpolate(x, size=(6, 8), scale_factor=2.0, mode="bilinear")
    with pytest.raises(mipnet.errors.ArgumentError, match="interpolate.*antialias"):
        M.interpolate(x, size=(6, 8), mode="bilinear", antialias=True)
    with pytest.raises(RuntimeError, match=r"interpolate.*4-D.*\[2, 3, 4\]"):
        M.interpolate(mipnet.tensor(rand((2, 3, 4))), size=(6, 8), mode="bilinear")
    with pytest.raises(RuntimeError, match=r"interpolate.*positive.*\[1, 2, 3, 4\]"):
        M.interpolate(x, scale_factor=0.1, mode="bilinear")
    with pytest.raises(RuntimeError, match=r"interpolate.*empty.*\[1, 0, 3, 4\]"):
        M.interpolate(mipnet.tensor(np.zeros((1, 0, 3, 4), np.float32)), size=(6, 8), mode="bilinear")


# ---- unfold / fold -------------------------------------------------------------------------------

GEOMETRIES = [dict(kernel_size=3, padding=1), dict(kernel_size=(2, 3), dilation=(2, 1), padding=(0, 2), stride=(2, 3)),
              dict(kernel_size=1), dict(kernel_size=(7, 6))]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("geo", GEOMETRIES)
def test_unfold_and_fold_match_torch(geo, dtype):
    check_op([rand((2, 3, 7, 6))], lambda x: F.unfold(x, **geo), lambda x: M.unfold(x, **geo), dtype=dtype)
    cols = F.unfold(torch.zeros(2, 3, 7, 6), **geo).shape
    check_op([rand(tuple(cols), seed=4)], lambda c: F.fold(c, (7, 6), **geo), lambda c: M.fold(c, (7, 6), **geo), dtype=dtype)


def test_unfold_fold_unbatched_and_non_contiguous():
    check_op([rand((3, 5, 4))], lambda x: F.unfold(x, 3, padding=1), lambda x: M.unfold(x, 3, padding=1))
    check_op([rand((27, 20))], lambda c: F.fold(c, (5, 4), 3, padding=1), lambda c: M.fold(c, (5, 4), 3, padding=1))
    x = non_contiguous(rand((2, 3, 5, 4)))
    np.testing.assert_array_equal(M.unfold(mipnet.tensor(x), 3, padding=1).numpy(),
                                  F.unfold(torch.tensor(np.ascontiguousarray(x)), 3, padding=1).numpy())


def test_unfold_fold_errors():
    x = mipnet.tensor(rand((1, 2, 2, 2)))
    with pytest.raises(RuntimeError, match=r"unfold.*larger than the padded input.*\[1, 2, 2, 2\]"):
        M.unfold(x, 5, padding=1)
    with pytest.raises(mipnet.errors.ArgumentError, match="unfold.*stride"):
        M.unfold(x, 3, stride=0)
    with pytest.raises(mipnet.errors.ArgumentError, match="unfold.*padding"):
        M.unfold(x, 3, padding=-1)
    with pytest.raises(RuntimeError, match=r"unfold.*4-D.*\[2, 2\]"):
        M.unfold(mipnet.tensor(rand((2, 2))), 1)
    with pytest.raises(RuntimeError, match=r"fold.*\[1, 18, 5\].*\[2, 2\]"):
        M.fold(mipnet.tensor(rand((1, 18, 5))), (2, 2), 3, padding=1)
    with pytest.raises(RuntimeError, match=r"fold.*larger.*\[1, 18, 4\]"):
        M.fold(mipnet.tensor(rand((1, 18, 4))), (2, 2), 5)
    with pytest.raises(RuntimeError, match=r"unfold.*empty.*\[1, 0, 3, 3\]"):
        M.unfold(mipnet.tensor(np.zeros((1, 0, 3, 3), np.float32)), 3)


def test_grid_sample_warp_of_the_1280_channel_stack_float32():
    flow = np.stack([-rand((1, 6, 10), np.float32, 0, 7, seed=8), np.zeros((1, 6, 10), np.float32)], 1)
    grid = _warp(lambda f, g: g, None, flow)
    check_op([rand((1, 1280, 6, 10)), grid], lambda x, g: F.grid_sample(x, g, padding_mode="border", align_corners=True),
             lambda x, g: M.grid_sample(x, g, padding_mode="border", align_corners=True))
