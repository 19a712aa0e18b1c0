"""Tests of the independent PyTorch reference (tests_py/reference) against the architecture spec.

These tests never import `mipnet`: they check the reference itself (state_dict names of architecture.md §2.10,
parameter counts of architecture.md §2.10, forward/training behaviour of §2.9, loss of §3.1).
"""

import os
import sys
from pathlib import Path

import pytest

if os.environ.get("CI"):
    import torch
else:
    torch = pytest.importorskip("torch")

import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))

from key_table import canonical_key_table  # noqa: E402
from reference import (  # noqa: E402
    MIPNetTorch,
    build_ip_stack,
    convex_upsample,
    ip_correlation,
    rls_correlation,
    sequence_loss_torch,
    warp,
)

torch.set_num_threads(2)

H, W = 64, 96
BUFFER_SUFFIXES = ("running_mean", "running_var", "num_batches_tracked")


def state_rows(model):
    return [(k, tuple(v.shape)) for k, v in model.state_dict().items()]


def images(n=1, h=H, w=W, seed=0):
    g = torch.Generator().manual_seed(seed)
    left = torch.rand(n, 3, h, w, generator=g) * 255
    # The right view is the left one shifted by a few pixels plus noise, so matching is meaningful.
    right = torch.roll(left, shifts=-4, dims=3) + torch.rand(n, 3, h, w, generator=g) * 10
    return left, right.clamp(0, 255)


def seeded_model(seed=0, **kwargs):
    torch.manual_seed(seed)
    return MIPNetTorch(**kwargs)


# ------------------------------------------------------------------------------------------------
# state_dict names, shapes and parameter counts (architecture.md §2.10)
# ------------------------------------------------------------------------------------------------


def test_spec_table_parsed_completely():
    rows = canonical_key_table()
    assert len(rows) == 428
    assert sum(1 for k, _ in rows if not k.endswith(BUFFER_SUFFIXES)) == 284


def test_state_dict_matches_spec_table_exactly():
    assert state_rows(MIPNetTorch()) == canonical_key_table()


@pytest.mark.parametrize(
    "kwargs, n_keys, n_params",
    [
        ({}, 428, 5_499_136),
        ({"use_aff": False}, 92, 5_371_712),
        ({"use_rls": False}, 398, 3_058_544),
        ({"use_ip": False}, 406, 3_669_008),
    ],
)
def test_ablation_keys_and_parameter_counts(kwargs, n_keys, n_params):
    model = MIPNetTorch(**kwargs)
    rows = state_rows(model)
    assert len(rows) == n_keys
    assert sum(p.numel() for p in model.parameters()) == n_params
    assert [k for k, _ in model.named_parameters()] == [
        k for k, _ in rows if not k.endswith(BUFFER_SUFFIXES)
    ]
    full = canonical_key_table()
    # every ablation keeps a subsequence of the canonical key table (names, order, shapes; architecture.md §2.10).
    it = iter(full)
    assert all(row in it for row in rows)


def test_rls_radius_changes_only_corr1():
    rows = dict(state_rows(MIPNetTorch(rx=2, ry=0)))
    assert rows["update_rls.motion.corr1.weight"] == (64, 5, 1, 1)
    default = dict(state_rows(MIPNetTorch()))
    assert {k for k in rows if rows[k] != default[k]} == {"update_rls.motion.corr1.weight"}


def test_backbone_kaiming_init_and_bn_defaults():
    model = seeded_model()
    w = model.encoder.layer3[1].conv1.weight
    expected_std = (2.0 / (w.shape[0] * 9)) ** 0.5
    assert abs(w.std().item() / expected_std - 1) < 0.05
    bn = model.encoder.layer1[0].fuse.att1.local.bn1
    assert torch.all(bn.weight == 1) and torch.all(bn.bias == 0)
    assert bn.eps == 1e-5 and bn.momentum == 0.1


# ------------------------------------------------------------------------------------------------
# Primitive operations (architecture.md §2.3, §2.5, §2.6, §2.8)
# ------------------------------------------------------------------------------------------------


def test_warp_integer_shift_clamps_at_border():
    feat = torch.arange(2 * 4 * 6, dtype=torch.float64).view(1, 2, 4, 6)
    flow = torch.zeros(1, 2, 4, 6, dtype=torch.float64)
    flow[:, 0] = -2
    out = warp(feat, flow)
    cols = (torch.arange(6) - 2).clamp(0, 5)
    assert torch.allclose(out, feat[:, :, :, cols])
    flow[:, 0] = 0.25
    out = warp(feat, flow)
    cols0 = torch.arange(6)
    cols1 = (cols0 + 1).clamp(max=5)
    assert torch.allclose(out, 0.75 * feat[..., cols0] + 0.25 * feat[..., cols1])


def test_ip_stack_slots_and_correlation_layout():
    torch.manual_seed(1)
    fr = torch.randn(1, 4, 5, 6, dtype=torch.float64)
    stack = build_ip_stack(fr)
    for s, (ox, oy) in enumerate([(0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1)]):
        rows = (torch.arange(5) + oy).clamp(0, 4)
        cols = (torch.arange(6) + ox).clamp(0, 5)
        assert torch.equal(stack[:, 4 * s : 4 * s + 4], fr[:, :, rows][:, :, :, cols])
    fl = torch.randn(1, 4, 5, 6, dtype=torch.float64)
    corr = ip_correlation(fl, stack)
    for g in range(2):
        for s in range(5):
            slot = stack[:, 4 * s + 2 * g : 4 * s + 2 * g + 2]
            expected = (fl[:, 2 * g : 2 * g + 2] * slot).mean(dim=1)
            assert torch.allclose(corr[:, 5 * g + s], expected)


def test_rls_correlation_candidate_order():
    torch.manual_seed(2)
    fl = torch.randn(1, 3, 5, 8, dtype=torch.float64)
    wf = torch.randn(1, 3, 5, 8, dtype=torch.float64)
    corr = rls_correlation(fl, wf, rx=3, ry=1)
    assert corr.shape == (1, 21, 5, 8)
    for i in range(7):
        for j in range(3):
            rows = (torch.arange(5) + j - 1).clamp(0, 4)
            cols = (torch.arange(8) + i - 3).clamp(0, 7)
            expected = (fl * wf[:, :, rows][:, :, :, cols]).mean(dim=1)
            assert torch.allclose(corr[:, 3 * i + j], expected)


def test_convex_upsample_neighbour_layout():
    torch.manual_seed(3)
    flow = torch.randn(1, 2, 3, 4, dtype=torch.float64)
    # A mask that selects neighbour k = 5 (dy = 0, dx = +1) for every sub-pixel.
    mask = torch.full((1, 144, 3, 4), -1e4, dtype=torch.float64)
    mask[:, 5 * 16 : 6 * 16] = 0
    up = convex_upsample(flow, mask)
    shifted = F.pad(flow, [0, 1, 0, 0])[:, :, :, 1:]
    expected = 4 * shifted.repeat_interleave(4, dim=2).repeat_interleave(4, dim=3)
    assert torch.allclose(up, expected)


# ------------------------------------------------------------------------------------------------
# Forward pass (architecture.md §2.9, §2.4 - §2.8)
# ------------------------------------------------------------------------------------------------


def test_eval_forward_shape_and_values():
    model = seeded_model().eval()
    left, right = images()
    with torch.no_grad():
        out = model(left, right, iters=(2, 2))
    assert out.shape == (1, 1, H, W)
    assert torch.isfinite(out).all()
    assert (out > 0).all()


def test_eval_forward_n4_zero_returns_handover_field():
    model = seeded_model().eval()
    left, right = images()
    with torch.no_grad():
        out = model(left, right, iters=(1, 0))
    assert out.shape == (1, 1, H, W)
    assert torch.isfinite(out).all()
    with pytest.raises(ValueError):
        model(left, right, iters=(0, 2))


@pytest.mark.parametrize(
    "kwargs, n_preds", [({}, 24), ({"use_rls": False}, 12), ({"use_ip": False}, 12)]
)
def test_training_forward_prediction_count(kwargs, n_preds):
    model = seeded_model(**kwargs).train()
    left, right = images()
    with torch.no_grad():
        preds = model(left, right)
    assert isinstance(preds, list) and len(preds) == n_preds
    assert all(p.shape == (1, 1, H, W) and torch.isfinite(p).all() for p in preds)


def test_training_forward_iters_int():
    model = seeded_model().train()
    left, right = images()
    with torch.no_grad():
        assert len(model(left, right, iters=2)) == 8
        assert len(model(left, right, iters=(3, 0))) == 6


def test_loss_backward_finite_grads_and_zero_delta_y_grad():
    model = seeded_model().train()
    left, right = images(n=2)
    gt = torch.full((2, 1, H, W), 20.0)
    valid = torch.ones(2, 1, H, W)
    preds = model(left, right, iters=(2, 2))
    assert len(preds) == 8
    loss = sequence_loss_torch(preds, gt, valid)
    loss.backward()
    assert torch.isfinite(loss)
    for name, p in model.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
    assert model.encoder.stem.conv.weight.grad.abs().sum() > 0
    for block in (model.update_ip, model.update_rls):
        head = block.disp_head.conv2
        # Vertical constraint: the Delta_y channel gets exactly zero gradient, Delta_x does not.
        assert torch.all(head.weight.grad[1] == 0) and head.bias.grad[1] == 0
        assert head.weight.grad[0].abs().sum() > 0
        # f_y is identically 0, so its input channel of the flow encoder gets exactly zero gradient.
        assert torch.all(block.motion.flow1.weight.grad[:, 1] == 0)


def test_vertical_constraint_off_keeps_f_y():
    model = seeded_model(vertical_constraint=False).train()
    left, right = images(n=2)
    preds = model(left, right, iters=(1, 1))
    sequence_loss_torch(preds, torch.full((2, 1, H, W), 20.0), torch.ones(2, 1, H, W)).backward()
    # f_y != 0 after the first IP update, so the RLS flow encoder's f_y input channel now learns.
    assert model.update_rls.motion.flow1.weight.grad[:, 1].abs().sum() > 0


def test_eval_gamma_draw_deterministic_and_global_rng_untouched():
    model = seeded_model().eval()
    left, right = images()
    torch.manual_seed(123)
    state = torch.get_rng_state()
    with torch.no_grad():
        a = model(left, right, iters=(1, 1))
        b = model(left, right, iters=(1, 1))
        c = model(left, right, iters=(1, 1), seed=21)
    assert torch.equal(torch.get_rng_state(), state)
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_eval_gamma_draw_follows_spec_formula_and_disp_init_is_honoured():
    model = seeded_model().eval()
    left, right = images()
    shape = (1, 1, H // 16, W // 16)
    g = torch.Generator().manual_seed(20)
    u1 = 1 - torch.rand(shape, generator=g)
    u2 = 1 - torch.rand(shape, generator=g)
    d0 = (-16.0 * (torch.log(u1) + torch.log(u2))).clamp(0, 192)
    with torch.no_grad():
        drawn = model(left, right, iters=(1, 1), seed=20)
        given = model(left, right, iters=(1, 1), seed=7, disp_init=d0 / 16)
        other = model(left, right, iters=(1, 1), disp_init=torch.full(shape, 3.0))
    assert torch.equal(drawn, given)
    assert not torch.allclose(drawn, other)
    with pytest.raises(ValueError):
        model(left, right, iters=(1, 1), disp_init=torch.ones(1, 1, 2, 2))


def test_disp_init_in_training_mode_skips_random_draw():
    model = seeded_model().train()
    model.freeze_bn()
    left, right = images()
    init = torch.full((1, 1, H // 16, W // 16), 2.0)
    state = torch.get_rng_state()
    with torch.no_grad():
        a = model(left, right, iters=(1, 1), disp_init=init)
        b = model(left, right, iters=(1, 1), disp_init=init)
    assert torch.equal(torch.get_rng_state(), state)
    assert all(torch.equal(x, y) for x, y in zip(a, b))


def test_training_mode_draws_from_global_rng():
    model = seeded_model().train()
    model.freeze_bn()
    left, right = images()
    with torch.no_grad():
        torch.manual_seed(5)
        a = model(left, right, iters=(1, 0))
        torch.manual_seed(5)
        b = model(left, right, iters=(1, 0))
        c = model(left, right, iters=(1, 0))
    assert torch.equal(a[-1], b[-1])
    assert not torch.equal(a[-1], c[-1])


def test_freeze_bn_keeps_running_stats():
    model = seeded_model().train()
    model.freeze_bn()
    bns = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert len(bns) == 48 and not any(m.training for m in bns)
    before = bns[0].running_mean.clone()
    left, right = images()
    with torch.no_grad():
        model(left, right, iters=(1, 0))
    assert torch.equal(bns[0].running_mean, before)


def test_float64_model_matches_float32():
    model = seeded_model().eval()
    left, right = images()
    init = torch.full((1, 1, H // 16, W // 16), 2.5)
    with torch.no_grad():
        out32 = model(left, right, iters=(1, 1), disp_init=init)
        model.double()
        out64 = model(left, right, iters=(1, 1), disp_init=init)
    assert out64.dtype == torch.float64
    assert torch.allclose(out64.float(), out32, atol=1e-2)


# ------------------------------------------------------------------------------------------------
# Sequence loss (architecture.md §3.1)
# ------------------------------------------------------------------------------------------------


def test_sequence_loss_values_and_masking():
    gt = torch.tensor([[[1.0, 2.0], [float("nan"), 800.0]]])  # (N,H,W) = (1,2,2)
    valid = torch.tensor([[[1.0, 0.4], [1.0, 1.0]]])
    p0 = torch.full((1, 1, 2, 2), 3.0, requires_grad=True)
    p1 = torch.full((1, 1, 2, 2), 0.0, requires_grad=True)
    loss = sequence_loss_torch([p0, p1], gt, valid)
    # Only pixel (0,0) is valid (gt 1): |3-1| * 0.8 + |0-1| * 1.
    assert torch.isclose(loss, torch.tensor(0.8 * 2 + 1.0))
    loss.backward()
    assert torch.isfinite(p0.grad).all() and torch.isfinite(p1.grad).all()
    assert p0.grad[0, 0, 0, 0] == pytest.approx(0.8) and p0.grad.abs().sum() == pytest.approx(0.8)


def test_sequence_loss_bool_valid_and_no_valid_pixel():
    gt = torch.ones(1, 1, 2, 2)
    pred = torch.full((1, 1, 2, 2), 4.0, requires_grad=True)
    assert sequence_loss_torch([pred], gt, torch.ones(1, 1, 2, 2, dtype=torch.bool)) == 3.0
    loss = sequence_loss_torch([pred], gt, torch.zeros(1, 1, 2, 2, dtype=torch.bool))
    assert loss == 0
    loss.backward()
    assert torch.all(pred.grad == 0)
    assert sequence_loss_torch([pred], gt, torch.ones(1, 1, 2, 2), max_disp=1.0) == 0
