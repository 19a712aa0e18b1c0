"""``mipnet adapt`` / ``mipnet.training.adapt``: the self-supervised losses and masks, a short run that lowers
the photometric loss and writes weights ``mipnet infer`` runs, the anchor, resume, and bad input."""

from __future__ import annotations

import os

import numpy as np
import pytest

import mipnet
import mipnet.cli
from mipnet.data import make_pair
from mipnet.errors import ArgumentError, ShapeError
from mipnet.model import photometric
from mipnet.model.pretrained import decode_metadata
from mipnet.serialization import load_safetensors
from mipnet.stereo import io
from mipnet.training import adapt
from mipnet.training.adapt import adapt_loss, anchor_penalty
from mipnet.training.checkpoint import load_latest_checkpoint
from mipnet.training.log import TrainLog

# 64x96 pairs, exactly the crop: with augment=False every step sees the same batch
TINY = dict(crop=(64, 96), iters=(1, 1), batch_size=2, workers=0, augment=False, progress=False)


def _write_pairs(folder, count: int = 2, size: tuple[int, int] = (64, 96)) -> tuple[str, str, list[dict]]:
    pairs = [make_pair(*size, seed=i) for i in range(count)]
    for side in ("L", "R"):
        os.makedirs(folder / side, exist_ok=True)
    for i, pair in enumerate(pairs):
        io.write_image(folder / "L" / f"{i:03d}.png", pair["left"])
        io.write_image(folder / "R" / f"{i:03d}.png", pair["right"])
    return str(folder / "L" / "*.png"), str(folder / "R" / "*.png"), pairs


def _nchw(pairs: list[dict], key: str) -> np.ndarray:
    return np.stack([p[key] for p in pairs]).transpose(0, 3, 1, 2).astype(np.float32)


def _fixed_loss(model, left, right) -> float:
    """The loss (without anchor) of one batch with the same initial draw for every model."""
    model.train()
    model.freeze_bn()
    mipnet.manual_seed(5)
    loss, _ = adapt_loss(model, left, right, (1, 1))
    return loss.item()


def _drift(run: str, start: dict) -> float:
    end = mipnet.load(os.path.join(run, "model.safetensors")).state_dict()
    return sum(float(((end[k] - start[k]) ** 2).sum()) for k, _ in mipnet.MIPNet().named_parameters())


# ---- the losses and masks ------------------------------------------------------------------------


def test_the_occlusion_mask_is_false_exactly_where_a_near_square_hides_the_far_plane():
    h, w = 32, 80
    far, near = 4.0, 12.0
    left = np.full((1, 1, h, w), far)
    left[..., 8:24, 40:60] = near  # the square in the left view, columns 40..59
    right = np.full((1, 1, h, w), far)
    right[..., 8:24, 28:48] = near  # the same square in the right view, columns 40 - 12 .. 59 - 12
    mask = photometric.lr_consistency_mask(left, right)
    expected = np.ones_like(mask)
    # far-plane left pixels x whose right pixel x - 4 lies on the square (28 <= x - 4 < 48) but not the square itself
    expected[..., 8:24, 32:40] = False
    np.testing.assert_array_equal(mask, expected)


def test_the_in_image_mask_and_the_warp_of_a_known_shift():
    rng = np.random.default_rng(0)
    right = rng.uniform(0, 255, (1, 3, 8, 12))
    disp = np.full((1, 1, 8, 12), 3.0)
    warped = photometric.warp_right_to_left(right, mipnet.Tensor(disp)).numpy()
    # left pixel x reads right pixel x - 3
    np.testing.assert_allclose(warped[..., 3:], right[..., :-3], atol=1e-3)
    inside = photometric.in_image_mask(disp)
    assert not inside[..., :3].any() and inside[..., 3:].all()


def test_the_ground_truth_disparity_reconstructs_the_left_view_better_than_a_wrong_one():
    pair = make_pair(64, 96, seed=3)
    left, right = _nchw([pair], "left"), _nchw([pair], "right")
    truth = pair["disparity"][None, None]
    valid = pair["valid"][None, None]
    good = photometric.photometric_loss(left, right, mipnet.Tensor(truth), valid).item()
    bad = photometric.photometric_loss(left, right, mipnet.Tensor(truth + 3), valid).item()
    assert good < 0.5 * bad


def test_the_composed_losses_and_their_gradients_match_torch():
    torch = pytest.importorskip("torch")
    F = torch.nn.functional
    rng = np.random.default_rng(1)
    n, h, w = 2, 12, 20
    left, right = rng.uniform(0, 255, (n, 3, h, w)), rng.uniform(0, 255, (n, 3, h, w))
    disp, mask = rng.uniform(0.5, 5, (n, 1, h, w)), rng.random((n, 1, h, w)) > 0.2
    g = rng.uniform(0.5, 2)
    d = mipnet.Tensor(disp, requires_grad=True)
    ours = photometric.photometric_loss(left, right, d, mask) + photometric.smoothness_loss(d, left) * g
    ours.backward()

    dt = torch.tensor(disp, requires_grad=True)
    lt, rt = torch.tensor(left) / 255, torch.tensor(right) / 255
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    grid = torch.stack([2 * (xs - dt[:, 0]) / (w - 1) - 1, (2 * ys / (h - 1) - 1).expand(n, h, w)], -1)
    warped = F.grid_sample(rt, grid, padding_mode="zeros", align_corners=True)

    def pool(t):
        return F.avg_pool2d(F.pad(t, (1, 1, 1, 1), mode="replicate"), 3, 1)

    mx, my = pool(lt), pool(warped)
    sx, sy, sxy = pool(lt * lt) - mx ** 2, pool(warped * warped) - my ** 2, pool(lt * warped) - mx * my
    ssim = (2 * mx * my + 1e-4) * (2 * sxy + 9e-4) / ((mx ** 2 + my ** 2 + 1e-4) * (sx + sy + 9e-4))
    error = (0.85 * torch.clamp((1 - ssim) / 2, 0, 1) + 0.15 * (warped - lt).abs()).mean(1, keepdim=True)
    keep = torch.tensor(mask) & (torch.arange(w) - dt.detach() >= 0) & (torch.arange(w) - dt.detach() <= w - 1)
    nd = dt / (dt.mean((2, 3), keepdim=True) + 1e-3)
    wx = torch.exp(-(lt[..., 1:] - lt[..., :-1]).abs().mean(1, keepdim=True))
    wy = torch.exp(-(lt[..., 1:, :] - lt[..., :-1, :]).abs().mean(1, keepdim=True))
    smooth = ((nd[..., 1:] - nd[..., :-1]).abs() * wx).mean() + ((nd[..., 1:, :] - nd[..., :-1, :]).abs() * wy).mean()
    theirs = (error * keep).sum() / keep.sum() + g * smooth
    theirs.backward()
    assert ours.item() == pytest.approx(theirs.item(), rel=1e-12)
    np.testing.assert_allclose(d.grad.numpy(), dt.grad.numpy(), rtol=1e-9, atol=1e-15)


def test_the_anchor_is_zero_at_the_start_and_grows_as_the_weights_move():
    model = mipnet.MIPNet()
    start = model.state_dict()
    assert anchor_penalty(model, start).item() == 0.0
    weight = model.encoder.stem.conv.weight
    weight.data = weight.data + np.float32(0.01)
    assert anchor_penalty(model, start).item() == pytest.approx(weight.data.size * 1e-4, rel=1e-4)


# ---- runs ----------------------------------------------------------------------------------------


def test_a_short_run_lowers_the_loss_and_writes_weights_that_infer_runs(tmp_path):
    left_glob, right_glob, pairs = _write_pairs(tmp_path)
    run = str(tmp_path / "run")
    left, right = _nchw(pairs, "left"), _nchw(pairs, "right")
    before = _fixed_loss(mipnet.MIPNet.pretrained(), left, right)
    records = adapt(left_glob, right_glob, run, steps=8, lr=1e-4, **TINY)
    assert [r["step"] for r in records] == list(range(1, 9))
    assert records[0]["anchor"] == 0.0 and records[-1]["drift"] > 0
    after = _fixed_loss(mipnet.load(os.path.join(run, "model.safetensors")), left, right)
    assert after < 0.9 * before

    logged = TrainLog(os.path.join(run, "log.jsonl")).records()
    assert {"loss", "photometric", "smoothness", "anchor", "consistent"} <= set(logged[-1])
    meta = decode_metadata(load_safetensors(os.path.join(run, "model.safetensors"))[1])
    assert "adapted without ground truth" in meta["trained"] and meta["adapt_pairs"] == 2 and meta["step"] == 8
    assert meta["adapted_from"].endswith("mipnet_pretrained.safetensors")
    assert meta["adapt_config"]["iters"] == [1, 1] and meta["adapt_config"]["anchor"] == 1e-2

    out = tmp_path / "infer"
    assert mipnet.cli.main(["infer", "--weights", os.path.join(run, "model.safetensors"), "-l", str(tmp_path / "L" / "000.png"),
                            "-r", str(tmp_path / "R" / "000.png"), "--iters", "1", "1", "-o", str(out)]) == 0
    assert (out / "000_disp.npy").exists()


def test_a_huge_anchor_keeps_the_weights_near_the_start(tmp_path):
    left_glob, right_glob, _ = _write_pairs(tmp_path)
    start = mipnet.MIPNet.pretrained().state_dict()
    settings = dict(steps=4, lr=1e-4, smoothness=0.0, gamma=0.0, **TINY)
    adapt(left_glob, right_glob, str(tmp_path / "free"), anchor=0.0, **settings)
    adapt(left_glob, right_glob, str(tmp_path / "held"), anchor=1e6, **settings)
    assert _drift(str(tmp_path / "held"), start) < 0.2 * _drift(str(tmp_path / "free"), start)


def test_resume_continues_at_the_saved_step_with_the_same_numbers(tmp_path):
    left_glob, right_glob, _ = _write_pairs(tmp_path, count=3)
    settings = dict(lr=1e-4, **{**TINY, "augment": True})
    whole = adapt(left_glob, right_glob, str(tmp_path / "whole"), steps=3, **settings)
    run = str(tmp_path / "split")
    adapt(left_glob, right_glob, run, steps=2, **settings)
    assert load_latest_checkpoint(run).step == 2
    resumed = adapt(None, None, run, steps=3, resume=True, progress=False)
    assert [r["step"] for r in resumed] == [3]
    assert [r["step"] for r in TrainLog(os.path.join(run, "log.jsonl")).records()] == [1, 2, 3]
    assert resumed[0]["loss"] == whole[-1]["loss"]
    with pytest.raises(ArgumentError, match="cannot change"):
        adapt(None, None, run, steps=4, resume=True, lr=1.0)
    with pytest.raises(ArgumentError, match="already holds a run"):
        adapt(left_glob, right_glob, run, steps=4, **settings)


# ---- bad input -----------------------------------------------------------------------------------


def test_pairs_of_different_sizes_raise_naming_both_files(tmp_path):
    left_glob, right_glob, _ = _write_pairs(tmp_path)
    io.write_image(tmp_path / "R" / "001.png", make_pair(64, 80, seed=9)["right"])
    with pytest.raises(ShapeError, match=r"L/001\.png.*R/001\.png"):
        adapt(left_glob, right_glob, str(tmp_path / "run"), steps=1, **TINY)


def test_an_empty_glob_or_unpaired_files_raise_naming_them(tmp_path, capsys):
    left_glob, right_glob, _ = _write_pairs(tmp_path)
    with pytest.raises(ArgumentError, match=r"nothing/\*\.png.*matches no file"):
        adapt(str(tmp_path / "nothing" / "*.png"), right_glob, str(tmp_path / "run"), steps=1, **TINY)
    io.write_image(tmp_path / "L" / "002.png", make_pair(64, 96, seed=9)["left"])
    with pytest.raises(ArgumentError, match=r"3 left images .* 2 right images.*L/002\.png"):
        adapt(left_glob, right_glob, str(tmp_path / "run"), steps=1, **TINY)
    status = mipnet.cli.main(["adapt", "--left", str(tmp_path / "none" / "*.png"), "--right", right_glob,
                              "--out", str(tmp_path / "cli"), "--quiet"])
    assert status == 2 and "mipnet adapt: error:" in capsys.readouterr().err


def test_the_command_line_has_help_and_runs_one_step(tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        mipnet.cli.main(["adapt", "--help"])
    assert done.value.code == 0 and "usage: mipnet adapt" in capsys.readouterr().out
    left_glob, right_glob, _ = _write_pairs(tmp_path)
    run = str(tmp_path / "run")
    assert mipnet.cli.main(["adapt", "--left", left_glob, "--right", right_glob, "--out", run, "--steps", "1",
                            "--crop", "64", "96", "--iters", "1", "1", "--workers", "0", "--quiet"]) == 0
    assert mipnet.cli.main(["adapt", "--resume", "--out", run, "--steps", "2", "--quiet"]) == 0
    assert load_latest_checkpoint(run).step == 2
