"""MIPNet's parameters, state dict, config and input handling (no PyTorch needed)."""


import numpy as np
import pytest

import mipnet
from helpers import require
from key_table import canonical_key_table

def test_state_dict_keys_order_and_shapes_equal_the_canonical_table():
    sd = mipnet.MIPNet().state_dict()
    assert [(k, tuple(v.shape)) for k, v in sd.items()] == canonical_key_table()


@pytest.mark.parametrize("config,params,keys", [
    ({}, 5_499_136, 428), ({"use_aff": False}, 5_371_712, 92),
    ({"use_rls": False}, 3_058_544, 398), ({"use_ip": False}, 3_669_008, 406)])
def test_parameter_counts_match_paper_table_1(config, params, keys):
    model = mipnet.MIPNet(**config)
    assert model.num_parameters() == params
    assert len(model.state_dict()) == keys


def test_rls_window_changes_only_corr1():
    a, b = mipnet.MIPNet().state_dict(), mipnet.MIPNet(rx=2, ry=0).state_dict()
    assert b["update_rls.motion.corr1.weight"].shape == (64, 5, 1, 1)
    assert [k for k in a if a[k].shape != b[k].shape] == ["update_rls.motion.corr1.weight"]


def test_load_state_dict_strict_reports_missing_and_unexpected():
    model = mipnet.MIPNet(use_rls=False)
    sd = mipnet.MIPNet().state_dict()
    with pytest.raises(RuntimeError, match="unexpected keys: \\['update_rls"):
        model.load_state_dict(sd)
    missing, unexpected = mipnet.MIPNet().load_state_dict(model.state_dict(), strict=False)
    assert not unexpected and len(missing) == 30 and all(k.startswith("update_rls.") for k in missing)


def test_load_state_dict_strips_module_prefix_and_checks_shapes():
    mipnet.manual_seed(1)
    src = mipnet.MIPNet().state_dict()
    dst = mipnet.MIPNet()
    dst.load_state_dict({"module." + k: v for k, v in src.items()})
    assert all(np.array_equal(v, src[k]) for k, v in dst.state_dict().items())
    bad = dict(src)
    bad["encoder.out.bias"] = np.zeros(3, np.float32)
    with pytest.raises(RuntimeError, match="size mismatch for encoder.out.bias"):
        dst.load_state_dict(bad)


def test_save_and_load_round_trip_config_and_weights(tmp_path):
    mipnet.manual_seed(2)
    model = mipnet.MIPNet(rx=2, use_aff=False)
    path = tmp_path / "w.safetensors"
    model.save(str(path), trained_on="nothing")
    back = mipnet.load(str(path))
    assert back.config == model.config
    for (k, a), (k2, b) in zip(model.state_dict().items(), back.state_dict().items()):
        assert k == k2 and a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)


def test_safetensors_files_match_the_reference_library(tmp_path):
    st = require("safetensors.numpy")
    from mipnet.serialization import load_safetensors, save_safetensors

    arrays = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "n": np.array(7, np.int64)}
    save_safetensors(tmp_path / "ours.st", arrays, {"k": "v"})
    theirs = st.load_file(str(tmp_path / "ours.st"))
    # safetensors.numpy returns 0-d tensors as shape (1,): compare values
    assert all(np.array_equal(theirs[k].reshape(v.shape), v) and theirs[k].dtype == v.dtype for k, v in arrays.items())
    st.save_file(arrays, str(tmp_path / "theirs.st"))
    ours, _ = load_safetensors(tmp_path / "theirs.st")
    assert all(np.array_equal(ours[k], v) and ours[k].shape == v.shape for k, v in arrays.items())


def test_average_of_weights_files_is_their_weighted_mean(tmp_path):
    from mipnet.serialization import average_safetensors, save_safetensors

    rng = np.random.default_rng(0)
    files = []
    for k in range(3):
        files.append(tmp_path / f"w{k}.safetensors")
        save_safetensors(files[-1], {"w": rng.standard_normal((4, 3)).astype(np.float16 if k == 0 else np.float32),
                                     "count": np.array([k], np.int64)})
    tensors = [mipnet.serialization.load_safetensors(f)[0] for f in files]
    mean = average_safetensors(files, [1.0, 2.0, 1.0])
    expected = (tensors[0]["w"].astype(np.float64) + 2 * tensors[1]["w"] + tensors[2]["w"]) / 4
    assert mean["w"].dtype == np.float32 and np.allclose(mean["w"], expected, rtol=1e-6, atol=1e-7)
    assert np.array_equal(mean["count"], [0])  # not a float: the first file's
    assert np.array_equal(average_safetensors(files[:1])["w"], tensors[0]["w"].astype(np.float32))
    save_safetensors(tmp_path / "other.safetensors", {"w": np.zeros((3, 4), np.float32), "count": np.zeros(1, np.int64)})
    with pytest.raises(mipnet.errors.FormatError, match=r"w is \(3, 4\) in .*other.safetensors"):
        average_safetensors([files[1], tmp_path / "other.safetensors"])
    with pytest.raises(mipnet.errors.ArgumentError, match="one non-negative weight per file"):
        average_safetensors(files, [1.0, -1.0, 1.0])


def test_corrupt_weights_file_raises_format_error(tmp_path):
    path = tmp_path / "bad.safetensors"
    path.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json")
    with pytest.raises(mipnet.errors.FormatError, match="bad.safetensors"):
        mipnet.load(str(path))


def test_double_and_float_cast_every_parameter_and_buffer():
    model = mipnet.MIPNet(use_rls=False).double()
    assert {p.dtype for p in model.parameters()} == {np.dtype(np.float64)}
    assert {np.asarray(b).dtype for n, b in model.named_buffers() if "num_batches" not in n} == {np.dtype(np.float64)}
    model.float()
    assert {p.dtype for p in model.parameters()} == {np.dtype(np.float32)}


def test_freeze_bn_survives_train():
    model = mipnet.MIPNet().freeze_bn().train()
    bns = [m for m in model.modules() if isinstance(m, mipnet.nn.BatchNorm2d)]
    assert len(bns) == 48 and not any(m.training for m in bns) and model.training


@pytest.mark.parametrize("left,right,match", [
    (np.zeros((64, 96, 3), np.uint8), np.zeros((64, 80, 3), np.uint8), "differ in shape"),
    (np.zeros((64, 96, 4), np.uint8), np.zeros((64, 96, 4), np.uint8), "HxW, HxWx1 or HxWx3"),
    (np.zeros((20, 96, 3), np.uint8), np.zeros((20, 96, 3), np.uint8), "smaller than 32x32"),
    (np.full((64, 96), np.nan, np.float32), np.zeros((64, 96), np.float32), "NaN"),
])
def test_bad_inputs_raise_clear_errors(left, right, match):
    with pytest.raises(RuntimeError, match=match):
        mipnet.MIPNet().eval()(left, right)


def test_gamma_draw_is_seeded_and_bounded():
    from mipnet.model import gamma_draw

    a = gamma_draw(np.random.default_rng(20), (2, 1, 30, 40), 2.0, 16.0, 192.0)
    b = gamma_draw(np.random.default_rng(20), (2, 1, 30, 40), 2.0, 16.0, 192.0)
    assert np.array_equal(a, b) and a.min() >= 0 and a.max() <= 192
    # Gamma(2, 16) has mean 32 px
    assert abs(gamma_draw(np.random.default_rng(0), (200_000,), 2.0, 16.0, 1e9).mean() - 32.0) < 0.3


def test_one_cycle_schedule_matches_torch_formula():
    p = mipnet.nn.Parameter(np.zeros(1, np.float32))
    opt = mipnet.optim.AdamW([p], lr=1.0)
    sched = mipnet.optim.OneCycleLR(opt, max_lr=6e-4, total_steps=200, pct_start=0.01)
    lrs = [sched.get_last_lr()[0]]
    for _ in range(199):
        sched.step()
        lrs.append(sched.get_last_lr()[0])
    assert lrs[0] == pytest.approx(6e-4 / 25) and lrs[1] == pytest.approx(6e-4)
    assert lrs[-1] == pytest.approx(6e-4 / 25 / 1e4) and all(a >= b for a, b in zip(lrs[1:], lrs[2:]))


def _shifted_texture_pair(h: int, w: int, shift: int) -> tuple[np.ndarray, np.ndarray]:
    """A fronto-parallel pair of constant disparity ``shift``: right(x) = left(x + shift)."""
    rng = np.random.default_rng(3)
    coarse = rng.uniform(0, 255, (h // 4 + 1, (w + shift) // 4 + 1, 3))
    # 4x nearest-upsampled noise plus fine noise: texture at two scales
    texture = np.repeat(np.repeat(coarse, 4, 0), 4, 1)[:h, :w + shift] * 0.7 + rng.uniform(0, 255, (h, w + shift, 3)) * 0.3
    texture = texture.astype(np.uint8)
    return texture[:, :w], texture[:, shift:shift + w]


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_scale_returns_disparity_in_input_pixels_at_the_input_size(scale):
    left, right = _shifted_texture_pair(128, 192, 12)
    disp = mipnet.MIPNet.pretrained()(left, right, scale=scale)
    assert disp.shape == (128, 192)
    # away from the borders (and the 12 occluded columns on the left) the shift is found in input pixels
    assert abs(float(np.median(disp[16:-16, 32:-16])) - 12.0) < 1.0


@pytest.mark.parametrize("scale,error,match", [
    (0.0, mipnet.errors.ArgumentError, "positive"),
    (-1.0, mipnet.errors.ArgumentError, "positive"),
    (float("nan"), mipnet.errors.ArgumentError, "positive"),
    (0.2, mipnet.errors.ShapeError, "smaller than 32x32"),
])
def test_bad_scale_raises_clear_errors(scale, error, match):
    left, right = _shifted_texture_pair(64, 96, 4)
    with pytest.raises(error, match=match):
        mipnet.MIPNet().eval()(left, right, scale=scale)


def test_scale_is_refused_in_training_mode():
    left, right = _shifted_texture_pair(64, 96, 4)
    with pytest.raises(mipnet.errors.ArgumentError, match="eval mode"):
        mipnet.MIPNet().train()(left, right, scale=0.5)
