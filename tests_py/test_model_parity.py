"""Whole-network parity: mipnet's MIPNet against the independent PyTorch reference
(tests_py/reference), same weights, same ``disp_init`` (architecture.md §2.4: gamma draws are engine-specific).

- eval, float32: final disparity within 1e-3 px (max abs), at 64x96 and at a size needing padding;
- training, float64: all 24 predictions, the sequence loss, every parameter gradient (relative error
  of the norm of the difference <= 1e-6; absolute tolerance for the biases whose gradient is zero in
  exact arithmetic, architecture.md §3.6) and the BatchNorm running statistics after the step;
- training, float32 with BatchNorm frozen: update-block gradients within 1e-3 relative (architecture.md §3.6).
"""

import numpy as np
import pytest

import mipnet
from helpers import require_torch

torch = require_torch()
F = torch.nn.functional
from reference import MIPNetTorch, sequence_loss_torch  # noqa: E402


def make_pair_models(dtype=np.float32, seed=0, **config):
    """A reference model with randomised BN running stats, and a mipnet model with its weights."""
    torch.manual_seed(seed)
    ref = MIPNetTorch(**config)
    with torch.no_grad():
        for m in ref.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.1, 0.1)
                m.running_var.uniform_(0.8, 1.2)
    ours = mipnet.MIPNet(**config)
    ours.load_state_dict({k: v.numpy() for k, v in ref.state_dict().items()})
    if dtype == np.float64:
        ref.double()
        ours.double()
    return ref, ours


def stereo_batch(n, h, w, seed=0):
    """A textured pair with a known shift, so the network sees structure (values 0..255)."""
    rng = np.random.default_rng(seed)
    left = rng.uniform(0, 255, size=(n, 3, h, w))
    right = np.roll(left, -3, axis=3) * 0.9 + rng.uniform(0, 25, size=left.shape)
    return left, right


def disp_init_for(n, h, w, seed=1):
    # positive 1/16-level disparity for the padded size (architecture.md §2.4)
    hp, wp = -(-h // 16) * 16, -(-w // 16) * 16
    return np.random.default_rng(seed).uniform(0.2, 2.5, size=(n, 1, hp // 16, wp // 16))


@pytest.mark.parametrize("h,w", [(64, 96), (50, 70)])
def test_eval_disparity_matches_reference_float32(h, w):
    ref, ours = make_pair_models()
    ref.eval(), ours.eval()
    left, right = stereo_batch(1, h, w)
    d0 = disp_init_for(1, h, w)
    ph, pw = -h % 16, -w % 16
    pad = [pw // 2, pw - pw // 2, ph // 2, ph - ph // 2]
    with torch.no_grad():
        tl, tr = (F.pad(torch.tensor(x, dtype=torch.float32), pad, mode="replicate") for x in (left, right))
        expected = ref(tl, tr, iters=(6, 6), disp_init=torch.tensor(d0, dtype=torch.float32))
        expected = expected[0, 0, pad[2]:pad[2] + h, pad[0]:pad[0] + w].numpy()
    got = ours(left.astype(np.float32), right.astype(np.float32), iters=(6, 6), disp_init=d0)
    assert got.shape == (1, h, w) and got.dtype == np.float32
    err = np.abs(got[0] - expected).max()
    print(f"\n[parity] eval float32 {h}x{w}: max |disparity error| = {err:.2e} px")
    assert err <= 1e-3, f"max abs disparity error {err:.2e} px"


def _train_step_both(dtype, freeze_bn, n=2, h=64, w=96):
    ref, ours = make_pair_models(dtype)
    ref.train(), ours.train()
    if freeze_bn:
        ref.freeze_bn(), ours.freeze_bn()
    left, right = stereo_batch(n, h, w)
    d0 = disp_init_for(n, h, w)
    gt = np.random.default_rng(3).uniform(0.5, 20, size=(n, 1, h, w))
    valid = np.random.default_rng(4).uniform(size=(n, 1, h, w)) > 0.2
    tdt = torch.float64 if dtype == np.float64 else torch.float32
    t_preds = ref(torch.tensor(left, dtype=tdt), torch.tensor(right, dtype=tdt), iters=(6, 6),
                  disp_init=torch.tensor(d0, dtype=tdt))
    t_loss = sequence_loss_torch(t_preds, torch.tensor(gt, dtype=tdt), torch.tensor(valid))
    t_loss.backward()
    m_preds = ours(left.astype(dtype), right.astype(dtype), iters=(6, 6), disp_init=d0)
    m_loss = mipnet.model.losses.sequence_loss(m_preds, gt.astype(dtype), valid)
    m_loss.backward()
    return ref, ours, t_preds, m_preds, t_loss, m_loss


def _zero_grad_bias(name):
    """Spec g.7: the 48 conv biases inside ``fuse`` (each feeds a training-mode BatchNorm) and the 19
    biases feeding an instance norm get a gradient that is zero in exact arithmetic."""
    if not name.endswith(".bias"):
        return False
    conv = name.rsplit(".", 2)[-2]
    feeds_batch_norm = ".fuse." in name and conv in ("conv1", "conv2")
    feeds_instance_norm = name == "encoder.stem.conv.bias" or (
        name.startswith("encoder.layer") and ".fuse." not in name and conv in ("conv1", "conv2", "proj"))
    return feeds_batch_norm or feeds_instance_norm


@pytest.mark.parametrize("heads", ["kept", "recomputed"])
def test_training_step_matches_reference_float64(heads, monkeypatch):
    """Both ways training treats the prediction heads (mipnet.model.memory.recompute_heads): kept at this
    size, and recomputed in the backward as at large sizes."""
    if heads == "recomputed":
        monkeypatch.setattr(mipnet.model.memory, "HEAD_KEEP_BYTES", 0)
    ref, ours, t_preds, m_preds, t_loss, m_loss = _train_step_both(np.float64, freeze_bn=False)
    assert len(m_preds) == len(t_preds) == 24
    worst_pred = max(np.abs(a.numpy() - b.detach().numpy()).max() for a, b in zip(m_preds, t_preds))
    print(f"\n[parity] train float64: max |prediction error| over 24 predictions = {worst_pred:.2e} px, "
          f"loss {m_loss.item():.12f} vs {t_loss.item():.12f}")
    for i, (a, b) in enumerate(zip(m_preds, t_preds)):
        np.testing.assert_allclose(a.numpy(), b.detach().numpy(), rtol=1e-9, atol=1e-8, err_msg=f"prediction {i}")
    assert m_loss.item() == pytest.approx(t_loss.item(), rel=1e-10)
    t_grads = {k: p.grad for k, p in ref.named_parameters()}
    rel = {}
    for name, p in ours.named_parameters():
        tg = t_grads[name]
        theirs = np.zeros(p.shape) if tg is None else tg.numpy()
        ours_g = np.zeros(p.shape) if p.grad is None else p.grad.numpy()
        diff = np.linalg.norm(ours_g - theirs)
        if _zero_grad_bias(name):
            assert diff <= 1e-8, f"{name}: |diff| {diff:.2e} (gradient zero in exact arithmetic)"
        else:
            rel[name] = diff / np.linalg.norm(theirs)
            assert diff <= 1e-6 * np.linalg.norm(theirs) + 1e-12, f"{name}: relative error {rel[name]:.2e}"
    worst = max(rel, key=rel.get)
    print(f"[parity] train float64: {len(rel)} parameter gradients, max relative error {rel[worst]:.2e} ({worst}), "
          f"median {np.median(list(rel.values())):.2e}")
    t_buffers = dict(ref.named_buffers())
    for name, b in ours.named_buffers():
        np.testing.assert_allclose(np.asarray(b), t_buffers[name].numpy(), rtol=1e-9, atol=1e-10, err_msg=name)


def test_training_step_frozen_bn_update_block_grads_match_reference_float32():
    ref, ours, _, m_preds, t_loss, m_loss = _train_step_both(np.float32, freeze_bn=True)
    assert m_loss.item() == pytest.approx(t_loss.item(), rel=1e-4)
    t_grads = dict(ref.named_parameters())
    rel = {}
    for name, p in ours.named_parameters():
        if not name.startswith("update_"):
            continue
        theirs = t_grads[name].grad.numpy()
        diff = np.linalg.norm(p.grad.numpy() - theirs)
        rel[name] = diff / (np.linalg.norm(theirs) + 1e-30)
        assert diff <= 1e-3 * np.linalg.norm(theirs) + 1e-6, f"{name}: relative error {rel[name]:.2e}"
    worst = max(rel, key=rel.get)
    print(f"\n[parity] train float32 frozen BN: {len(rel)} update-block gradients, max relative error "
          f"{rel[worst]:.2e} ({worst}), loss {m_loss.item():.6f} vs {t_loss.item():.6f}")
