"""``mipnet train`` / ``mipnet.training.fit``: a short run, exact resume, SIGTERM, damaged checkpoints,
configuration resolution, data specs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import mipnet
import mipnet.cli
from mipnet.errors import ArgumentError, FormatError
from mipnet.training import fit, resolve_config
from mipnet.training import checkpoint
from mipnet.training.checkpoint import list_checkpoints, load_latest_checkpoint
from mipnet.data.registry import Mixture, parse_spec
from mipnet.serialization import save_safetensors
from mipnet.training.log import TrainLog
from mipnet.training.validation import photo_pairs_available

TINY = ["--crop", "64", "96", "--batch-size", "2", "--iters", "1", "1", "--val-every", "0", "--workers", "0",
        "--data", "scenes:0.5", "synthetic:0.5", "--quiet"]


def _tiny_config(**kw):
    settings = dict(crop=(64, 96), batch_size=2, iters=(1, 1), val_every=0, workers=0, steps=6, checkpoint_every=100,
                    data=["scenes:0.5", "synthetic-underwater:0.5"])
    settings.update(kw)
    return resolve_config("cpu", overrides=settings)


def _losses(run: str) -> list[float]:
    return [r["loss"] for r in TrainLog(os.path.join(run, "log.jsonl")).records() if "loss" in r]


def _weights(run: str) -> dict:
    return mipnet.load(os.path.join(run, "model.safetensors")).state_dict()


def test_cli_two_steps_writes_log_weights_checkpoint(tmp_path):
    run = str(tmp_path / "run")
    assert mipnet.cli.main(["train", "--preset", "cpu", "--steps", "2", "--out", run] + TINY) == 0
    records = TrainLog(os.path.join(run, "log.jsonl")).records()
    assert [r["step"] for r in records] == [1, 2]
    for r in records:
        assert {"step", "loss", "lr", "epe", "seconds"} <= set(r)
        assert np.isfinite(r["loss"]) and r["loss"] > 0 and r["seconds"] > 0
    model = mipnet.load(os.path.join(run, "model.safetensors"))
    assert model.num_parameters() == mipnet.MIPNet().num_parameters()
    assert load_latest_checkpoint(run).step == 2
    config = json.load(open(os.path.join(run, "config.json")))
    assert config["crop"] == [64, 96] and config["iters"] == [1, 1] and config["lr"] == 4e-4  # cpu preset's LR


@pytest.mark.parametrize("ema_decay", [0.0, 0.9])
def test_resume_is_bitwise_identical(tmp_path, ema_decay):
    straight, split = str(tmp_path / "straight"), str(tmp_path / "split")
    fit(_tiny_config(steps=6, ema_decay=ema_decay), straight, progress=False)
    fit(_tiny_config(steps=3, schedule_steps=6, ema_decay=ema_decay), split, progress=False)
    assert load_latest_checkpoint(split).step == 3
    fit(None, split, resume=True, steps=6, progress=False)
    assert _losses(straight) == _losses(split)
    assert len(_losses(split)) == 6
    a, b = _weights(straight), _weights(split)
    assert list(a) == list(b)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_a_run_with_ema_decay_saves_the_average_of_its_steps(tmp_path):
    """model.safetensors holds the checkpoint's moving average, which is neither the last step's weights
    nor the initial ones; the model trains on from its own weights."""
    run = str(tmp_path / "run")
    fit(_tiny_config(steps=3, ema_decay=0.5), run, progress=False)
    state = load_latest_checkpoint(run)
    saved = _weights(run)
    assert state.average is not None and set(state.average) < set(saved)
    moved = 0
    for name, avg in state.average.items():
        np.testing.assert_array_equal(saved[name], avg, err_msg=name)
        moved += not np.array_equal(avg, state.model[name])
    assert moved > 0
    for name in set(saved) - set(state.average):  # BatchNorm's running statistics: the model's own
        np.testing.assert_array_equal(saved[name], state.model[name], err_msg=name)


def _tiny_state(step=5):
    model = {"w": np.arange(6, dtype=np.float32).reshape(2, 3)}
    optimizer = {"state": {0: {"step": np.array(2), "exp_avg": np.ones((2, 3), np.float32)}},
                 "param_groups": [{"lr": 1e-4}]}
    return checkpoint.TrainState(step=step, epoch=0, batch=step, model=model, optimizer=optimizer,
                                 schedule={"last_step": step}, rng_state={"state": 1},
                                 config_json=mipnet.training.TrainConfig().to_json(), model_config="{}")


def test_the_digest_covers_the_metadata_so_an_altered_step_is_detected(tmp_path):
    tensors, meta = checkpoint._flatten(_tiny_state())
    path = str(tmp_path / "ckpt.safetensors")
    save_safetensors(path, tensors, {**meta, "step": "0"})
    with pytest.raises(FormatError, match="digest mismatch"):
        checkpoint.read_checkpoint(path)
    save_safetensors(path, tensors, meta)
    assert checkpoint.read_checkpoint(path).step == 5


def test_a_checkpoint_of_the_first_format_still_loads(tmp_path):
    """mipnet-checkpoint-1 files (runs written before the digest covered the metadata) resume as before."""
    tensors, meta = checkpoint._flatten(_tiny_state(7))
    meta.update(format=checkpoint.TENSOR_DIGEST_FORMAT, digest=checkpoint._digest(tensors))
    path = str(tmp_path / "ckpt.safetensors")
    save_safetensors(path, tensors, meta)
    assert checkpoint.read_checkpoint(path).step == 7


def test_damaged_checkpoint_falls_back_to_previous(tmp_path, caplog):
    run = str(tmp_path / "run")
    fit(_tiny_config(steps=4, checkpoint_every=2), run, progress=False)
    newest, older = list_checkpoints(run)
    with open(newest, "r+b") as f:  # flip bytes inside the tensor data: the digest no longer matches
        f.seek(os.path.getsize(newest) - 100)
        f.write(b"\xff" * 8)
    assert load_latest_checkpoint(run).step == 2
    assert "digest mismatch" in caplog.text
    with open(older, "wb") as f:
        f.write(b"\x00" * 5)
    with pytest.raises(FormatError, match="every checkpoint is unreadable"):
        load_latest_checkpoint(run)


def test_resume_after_a_damaged_newest_checkpoint_redoes_its_steps(tmp_path):
    straight, run = str(tmp_path / "straight"), str(tmp_path / "run")
    fit(_tiny_config(steps=4), straight, progress=False)
    fit(_tiny_config(steps=4, checkpoint_every=2), run, progress=False)
    with open(list_checkpoints(run)[0], "wb") as f:
        f.write(b"truncated")
    fit(None, run, resume=True, steps=4, progress=False)
    assert _losses(run) == _losses(straight)


def test_sigterm_checkpoints_and_resumes(tmp_path):
    run, straight = str(tmp_path / "run"), str(tmp_path / "straight")
    args = [sys.executable, "-m", "mipnet", "train", "--preset", "cpu", "--steps", "200", "--out", run] + TINY
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, env={**os.environ, "MIPNET_NUM_THREADS": "1"})
    log = os.path.join(run, "log.jsonl")
    deadline = time.time() + 240
    while time.time() < deadline and (not os.path.exists(log) or len(TrainLog(log).records()) < 2):
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=240)
    assert proc.returncode == 0, err
    assert "SIGTERM received" in err and "--resume" in err
    stopped = load_latest_checkpoint(run).step
    assert 2 <= stopped < 200 and len(_losses(run)) == stopped
    assert mipnet.cli.main(["train", "--resume", run, "--steps", str(stopped + 1), "--quiet"]) == 0
    fit(resolve_config("cpu", overrides=dict(steps=200, crop=(64, 96), batch_size=2, iters=(1, 1), val_every=0,
                                             workers=0, data=["scenes:0.5", "synthetic:0.5"])),
        straight, steps=stopped + 1, progress=False)
    assert _losses(run) == _losses(straight)


def test_validation_records_and_best_weights(tmp_path):
    run = str(tmp_path / "run")
    fit(_tiny_config(steps=2, val_every=2, val_pairs=1, val_size=(64, 96), val_iters=(1, 1)), run, progress=False)
    vals = [r for r in TrainLog(os.path.join(run, "log.jsonl")).records() if "val" in r]
    assert len(vals) == 1 and vals[0]["step"] == 2
    photos = {"photos"} if photo_pairs_available() else set()
    assert set(vals[0]["val"]) == {"air", "turbid", "low_light", "turbid_survey", "low_light_survey", "scenes",
                                   "scenes_veiled"} | photos
    for metrics in vals[0]["val"].values():
        assert metrics["epe"] > 0 and 0 <= metrics["bad3"] <= 100
    assert os.path.isfile(os.path.join(run, "best.safetensors"))
    path = mipnet.training.plot(run)
    assert os.path.getsize(path) > 1000


def test_workers_give_the_same_losses(tmp_path):
    a, b = str(tmp_path / "a"), str(tmp_path / "b")
    fit(_tiny_config(steps=2, workers=0), a, progress=False)
    fit(_tiny_config(steps=2, workers=1), b, progress=False)
    assert _losses(a) == _losses(b)


def test_config_precedence_preset_file_flags(tmp_path):
    toml = tmp_path / "run.toml"
    toml.write_text('preset = "cpu"\nbatch_size = 3\nlr = 1e-4\ndata = ["synthetic"]\n')
    from mipnet.training.config import read_config_file

    config = resolve_config(None, read_config_file(str(toml)), {"lr": 2e-4, "steps": None})
    assert config.crop == (128, 256)  # from the preset
    assert config.batch_size == 3  # the file over the preset
    assert config.lr == 2e-4  # the flag over the file
    assert config.data == ["synthetic"]


@pytest.mark.parametrize("settings, message", [
    ({"bogus": 1}, "unknown setting"),
    ({"crop": (50, 96)}, "multiples of 16"),
    ({"steps": 0}, "steps must be positive"),
    ({"veil": 1.5}, "veil is a probability"),
    ({"noise": -0.1}, "noise is a probability"),
    ({"spatial_scale": (0.4, -0.2)}, "low <= high"),
    ({"spatial_scale": (0.1,)}, "spatial_scale must be two finite numbers"),
])
def test_bad_settings_raise(settings, message):
    with pytest.raises(ArgumentError, match=message):
        resolve_config("cpu", overrides=settings)


@pytest.mark.parametrize("setting, option", [("veil", "veil_prob"), ("noise", "noise_prob")])
def test_augmentation_probability_reaches_every_augmentor_only_with_augment(setting, option):
    from mipnet.training.config import TrainConfig
    from mipnet.training.fit import build_dataset

    config = resolve_config("cpu", overrides={setting: 0.3, "data": ["synthetic", "scenes"]})
    _, augmentors = build_dataset(config)
    assert [getattr(a, option) for a in augmentors] == [0.3, 0.3]
    _, plain = build_dataset(resolve_config("cpu", overrides={setting: 0.3, "augment": False, "data": ["synthetic"]}))
    assert getattr(plain[0], option) == 0.0
    # a run written before the setting existed resumes without the augmentation
    old = json.loads(config.to_json())
    del old[setting]
    assert getattr(TrainConfig.from_json(json.dumps(old)), setting) == 0.0


def test_noise_sources_air_leaves_the_generated_under_water_sources_as_rendered():
    from mipnet.training.config import TrainConfig
    from mipnet.training.fit import build_dataset

    data = ["synthetic", "scenes-underwater", "scenes", "synthetic-underwater"]
    config = resolve_config("cpu", overrides={"noise": 0.3, "noise_sources": "air", "data": data})
    _, augmentors = build_dataset(config)
    assert [a.noise_prob for a in augmentors] == [0.3, 0.0, 0.3, 0.0]
    assert TrainConfig.from_json(config.to_json()).noise_sources == "air"
    # a run written before the setting existed resumes with the noise on every source, as it ran
    old = json.loads(config.to_json())
    del old["noise_sources"]
    assert TrainConfig.from_json(json.dumps(old)).noise_sources == "all"
    with pytest.raises(ArgumentError, match="noise_sources must be one of"):
        resolve_config("cpu", overrides={"noise_sources": "water"})


def test_spatial_scale_reaches_every_augmentor_and_survives_a_resume():
    from mipnet.training.config import TrainConfig
    from mipnet.training.fit import build_dataset

    config = resolve_config("cpu", overrides={"spatial_scale": (-0.3, 0.1), "data": ["synthetic", "scenes"]})
    _, augmentors = build_dataset(config)
    assert [a.scale_range for a in augmentors] == [(-0.3, 0.1), (-0.3, 0.1)]
    assert TrainConfig.from_json(config.to_json()).spatial_scale == (-0.3, 0.1)
    # a run written before the setting existed resumes with RAFT-Stereo's range
    old = json.loads(config.to_json())
    del old["spatial_scale"]
    assert TrainConfig.from_json(json.dumps(old)).spatial_scale == (-0.2, 0.4)


def test_veiled_validation_set_fades_the_lower_rows_and_stays_out_of_the_mean():
    from mipnet.training.validation import mean_epe, validation_sets

    sets = validation_sets((96, 128), 2)
    plain, veiled = sets["scenes"][1], sets["scenes_veiled"][1]
    assert len(sets["scenes_veiled"]) == 2
    np.testing.assert_array_equal(veiled["disparity"], plain["disparity"])
    np.testing.assert_array_equal(veiled["left"][:20], plain["left"][:20])  # above the veil's soft edge
    for view in ("left", "right"):
        # the bottom rows keep a fifth of their contrast around the pale veil colour
        assert veiled[view][-10:].std() < 0.3 * plain[view][-10:].std() + 1.0
        assert veiled[view][-10:].mean() > 150
    table = {k: {"epe": float(i + 1)} for i, k in enumerate(("air", "turbid", "low_light", "scenes"))}
    assert mean_epe({**table, "scenes_veiled": {"epe": 100.0}}) == mean_epe(table) == 2.5
    # with the survey-like sets the under-water terms are theirs, not the sets where the water hides most pixels
    survey = {**table, "turbid_survey": {"epe": 10.0}, "low_light_survey": {"epe": 20.0}}
    assert mean_epe(survey) == (1 + 10 + 20 + 4) / 4


def test_bad_config_file_and_presets(tmp_path):
    from mipnet.training.config import read_config_file

    bad = tmp_path / "bad.toml"
    bad.write_text("steps = [")
    with pytest.raises(ArgumentError, match="not valid TOML"):
        read_config_file(str(bad))
    with pytest.raises(ArgumentError, match="unknown preset"):
        resolve_config("fast")
    with pytest.raises(ArgumentError, match="needs --init"):
        resolve_config("finetune")


def test_existing_run_needs_resume(tmp_path):
    run = str(tmp_path / "run")
    fit(_tiny_config(steps=1), run, progress=False)
    with pytest.raises(ArgumentError, match="already holds a run"):
        fit(_tiny_config(steps=1), run, progress=False)
    with pytest.raises(ArgumentError, match="cannot change"):
        fit(None, run, resume=True, steps=2, progress=False, overrides={"lr": 1.0})
    with pytest.raises(ArgumentError, match="schedule of this run ends"):
        fit(None, run, resume=True, steps=10_000, progress=False)


def test_data_specs():
    assert parse_spec("scenes") == parse_spec("scenes:1")
    assert parse_spec("synthetic:0.25").weight == 0.25
    kitti = parse_spec("kitti2015:/data/kitti:0.3")
    assert (kitti.name, kitti.root, kitti.weight) == ("kitti2015", "/data/kitti", 0.3)
    assert parse_spec("folder:/my/pairs").root == "/my/pairs"
    for text, message in [("nosuch", "unknown dataset"), ("kitti2015", "needs a root"), ("scenes:/x", "takes no root"),
                          ("synthetic:-1", "positive")]:
        with pytest.raises(ArgumentError, match=message):
            parse_spec(text)


def test_mixture_follows_weights_and_is_deterministic():
    class Numbers(mipnet.data.Dataset):
        def __init__(self, tag, n):
            self.tag, self.n = tag, n

        def __len__(self):
            return self.n

        def __getitem__(self, i):
            return {"tag": self.tag, "i": i}

    mix = Mixture([Numbers("a", 10), Numbers("b", 3)], [0.8, 0.2], 5000, seed=7)
    tags = [mix[i]["tag"] for i in range(5000)]
    assert abs(tags.count("a") / 5000 - 0.8) < 0.03
    assert [mix[i] for i in range(50)] == [Mixture([Numbers("a", 10), Numbers("b", 3)], [0.8, 0.2], 5000, seed=7)[i]
                                           for i in range(50)]
    assert all(0 <= mix[i]["i"] < (10 if mix[i]["tag"] == "a" else 3) for i in range(200))


def test_shipped_weights_carry_the_history_of_their_init(tmp_path):
    # scripts/ship_weights.py: a run continued from shipped weights adds its steps to theirs
    ship = os.path.join(os.path.dirname(__file__), "..", "scripts", "ship_weights.py")
    first, second = str(tmp_path / "first"), str(tmp_path / "second")
    fit(_tiny_config(steps=2), first, progress=False)
    shipped_first = str(tmp_path / "first.safetensors")
    subprocess.run([sys.executable, ship, first, "--weights", "model.safetensors", "--out", shipped_first], check=True)
    fit(_tiny_config(steps=1, init=shipped_first), second, progress=False)
    shipped_second = str(tmp_path / "second.safetensors")
    subprocess.run([sys.executable, ship, second, "--weights", "model.safetensors", "--out", shipped_second], check=True)
    from mipnet.serialization import load_safetensors
    tensors_first, meta_first = load_safetensors(shipped_first)
    tensors, meta = load_safetensors(shipped_second)
    assert meta_first["step"] == "2" and meta_first["trained"].startswith("2 steps from scratch")
    assert meta["step"] == "3"
    assert meta["trained"].startswith("3 steps: " + meta_first["trained"] + "; then 1 more from those weights")
    assert all(v.dtype == np.float16 for v in tensors.values() if v.dtype.kind == "f")
    assert mipnet.load(shipped_second).state_dict().keys() == _weights(second).keys()
    # --average: the mean of this run's weights and earlier shipped ones of its lineage, named in the metadata
    shipped_mean = str(tmp_path / "mean.safetensors")
    subprocess.run([sys.executable, ship, second, "--weights", "model.safetensors", "--out", shipped_mean,
                    "--average", shipped_first], check=True)
    mean, meta_mean = load_safetensors(shipped_mean)
    assert meta_mean["step"] == "3" and json.loads(meta_mean["averaged_steps"]) == [2, 3]
    assert meta_mean["trained"].startswith("the mean of the weights after 2 and 3 steps")
    last, _ = load_safetensors(os.path.join(second, "model.safetensors"))
    name = "encoder.stem.conv.weight"
    expected = (tensors_first[name].astype(np.float64) + last[name]) / 2
    assert np.allclose(mean[name], expected, rtol=2e-3, atol=1e-4)  # float16 of the float32 mean
    failed = subprocess.run([sys.executable, ship, first, "--weights", "model.safetensors", "--out", shipped_mean,
                             "--average", shipped_second], capture_output=True, text=True)
    assert failed.returncode != 0 and "not earlier" in failed.stderr


def test_campaign_history_reads_every_committed_version_of_the_weights(tmp_path):
    # scripts/campaign_history.py: steps and validation EPE from each committed version's metadata, oldest first
    import importlib.util
    from safetensors.numpy import save_file
    script = os.path.join(os.path.dirname(__file__), "..", "scripts", "campaign_history.py")
    spec = importlib.util.spec_from_file_location("campaign_history", script)
    history = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(history)
    repo, weights = tmp_path / "repo", tmp_path / "repo" / history.WEIGHTS
    weights.parent.mkdir(parents=True)
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(git[:3] + ["init", "-q"], check=True)
    setup = json.dumps({"pairs": 32, "size": [384, 512]})
    versions = [({"step": "10"}, None), ({"step": "20", "validation_setup": setup}, 2.0),
                ({"step": "30", "validation_setup": setup}, 1.5)]
    for meta, epe in versions:
        if epe is not None:
            table = {"air": {"epe": epe / 4}, "turbid": {"epe": epe}, "cones": {"epe": epe + 1}}
            meta = dict(meta, validation=json.dumps(table), validation_sgbm=json.dumps({"air": {"epe": 4.0}}))
        save_file({"w": np.zeros(2, np.float16)}, str(weights), metadata=meta)
        subprocess.run(git + ["add", "-A"], check=True)
        subprocess.run(git + ["commit", "-qm", meta["step"]], check=True)
    points = history.history(str(repo))
    # the first version has no validation table: left out
    assert [p["step"] for p in points] == [20, 30]
    assert [p["epe"]["turbid"] for p in points] == [2.0, 1.5] and points[1]["epe"]["cones"] == 2.5
    assert points[0]["setup"] == "32 pairs, 384x512" and points[1]["sgbm"] == {"air": 4.0}
    out = tmp_path / "history.png"
    history.plot(points, str(out))
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
