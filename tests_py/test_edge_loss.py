"""sequence_loss's edge term: which pixels count as near a depth jump, and what the term adds to the loss and its
gradient (docs/training.md, "The bleed is in the matching at 1/4 resolution")."""

import numpy as np
import pytest
from scipy import ndimage

import mipnet
from mipnet.errors import ArgumentError
from mipnet.model.losses import EDGE_JUMP, near_jump, sequence_loss
from mipnet.training import TrainConfig


def _jumps(gt: np.ndarray, ok: np.ndarray, jump: float) -> np.ndarray:
    """Both pixels of every neighbouring valid pair whose disparities differ by more than ``jump``, by loops."""
    edge = np.zeros_like(ok)
    height, width = gt.shape
    for y in range(height):
        for x in range(width):
            for dy, dx in ((0, 1), (1, 0)):
                y2, x2 = y + dy, x + dx
                if y2 < height and x2 < width and ok[y, x] and ok[y2, x2] and abs(gt[y, x] - gt[y2, x2]) > jump:
                    edge[y, x] = edge[y2, x2] = True
    return edge


@pytest.mark.parametrize("radius", [0, 1, 3, 12])
def test_near_jump_is_the_square_dilation_of_the_jumps_within_valid(radius):
    rng = np.random.default_rng(radius)
    # a step field (steps of 0-6 px between blocks) with holes in the ground truth
    gt = np.kron(rng.uniform(0, 30, (4, 5)), np.ones((7, 9))) + rng.uniform(0, 0.5, (28, 45))
    ok = rng.uniform(size=gt.shape) > 0.1
    want = ndimage.maximum_filter(_jumps(gt, ok, EDGE_JUMP), size=2 * radius + 1, mode="constant") & ok
    got = near_jump(gt[None, None], ok[None, None], radius=radius)[0, 0]
    np.testing.assert_array_equal(got, want)
    assert got.any() and not got.all()


def test_a_smooth_field_has_no_pixel_near_a_jump():
    gt = np.tile(np.linspace(0, 40, 64), (32, 1))  # a slant: 0.63 px between neighbours
    assert not near_jump(gt, np.ones_like(gt, bool)).any()


def test_edge_weight_adds_the_mean_error_near_jumps_to_each_prediction():
    rng = np.random.default_rng(0)
    gt = np.where(np.arange(48)[None, :] < 20, 30.0, 10.0) * np.ones((2, 1, 24, 48))
    valid = rng.uniform(size=gt.shape) > 0.2
    preds = [mipnet.tensor(gt + rng.normal(0, 2, gt.shape), requires_grad=True) for _ in range(3)]
    plain = float(sequence_loss(preds, gt, valid, gamma=0.8).numpy())
    loss = sequence_loss(preds, gt, valid, gamma=0.8, edge_weight=2.5)
    near = near_jump(gt, valid)
    # L = Σ_i 0.8^(2-i) (mean_valid |e_i| + 2.5 mean_near |e_i|)
    extra = sum(0.8 ** (2 - i) * np.abs(p.numpy() - gt)[near].mean() for i, p in enumerate(preds))
    assert float(loss.numpy()) == pytest.approx(plain + 2.5 * extra, rel=1e-9)
    loss.backward()
    # d/dp of the last prediction: sign(e) (1 / #valid + 2.5 / #near on near pixels), 0 where invalid
    sign = np.sign(preds[-1].numpy() - gt)
    want = sign * (valid / valid.sum() + 2.5 * near / near.sum())
    np.testing.assert_allclose(preds[-1].grad.numpy(), want, rtol=1e-9, atol=1e-15)


def test_edge_weight_is_a_checked_setting():
    assert TrainConfig(edge_weight=0.5).edge_weight == 0.5
    with pytest.raises(ArgumentError, match="edge_weight"):
        TrainConfig(edge_weight=-1.0)
    with pytest.raises(ArgumentError, match="edge_weight"):
        TrainConfig(edge_weight=float("nan"))
