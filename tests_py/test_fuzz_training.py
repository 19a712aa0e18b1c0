"""Fuzzing the training run readers: the TOML run file (``mipnet train --config``) and the checkpoint
reader. Any input is read correctly or raises the documented error naming the file."""

from __future__ import annotations

import json

import numpy as np
from fuzzing import assert_reads_or_raises, fuzz_settings, mutations, written_bytes
from hypothesis import given
from hypothesis import strategies as st

from mipnet.errors import ArgumentError, FormatError
from mipnet.training.checkpoint import TrainState, _flatten, read_checkpoint
from mipnet.training.config import TrainConfig, load_config_file
from mipnet.serialization import save_safetensors

CONFIG_SEEDS = [
    b'preset = "cpu"\nsteps = 300\ncrop = [128, 256]\niters = [3, 3]\nlr = 4e-4\ndata = ["scenes:0.7", "synthetic:0.3"]\n',
    b'batch_size = 2\nval_size = [64, 96]\nfreeze_bn = true\ninit = "w.safetensors"\nschedule_steps = 10\n',
    b'steps = 0\ncrop = [50, 96]\n',
    b'data = 5\nlr = "fast"\n[extra]\nx = 1\n',
]


def _check_config(config):
    assert isinstance(config, TrainConfig)
    assert config.steps > 0 and min(config.crop) >= 32 and all(isinstance(d, str) for d in config.data)


@fuzz_settings(300)
@given(mutations(CONFIG_SEEDS))
def test_config_file_reads_or_raises(data):
    assert_reads_or_raises(load_config_file, data, allowed=(ArgumentError,), suffix=".toml", check=_check_config)


_TOML_VALUES = st.one_of(st.integers(-2**70, 2**70), st.floats(allow_nan=True), st.text(max_size=8), st.booleans(),
                         st.lists(st.integers(-5, 600), max_size=3), st.lists(st.text(max_size=6), max_size=3))


@fuzz_settings(200)
@given(st.dictionaries(st.sampled_from(sorted(TrainConfig.__dataclass_fields__) + ["preset", "bogus"]), _TOML_VALUES,
                       max_size=6))
def test_config_file_with_any_values(settings):
    lines = [f"{k} = {json.dumps(v)}" if not (isinstance(v, float) and not np.isfinite(v)) else f"{k} = {str(v).lower()}"
             for k, v in settings.items()]
    assert_reads_or_raises(load_config_file, "\n".join(lines).encode(), allowed=(ArgumentError,), suffix=".toml",
                           check=_check_config)


def _state(**meta_overrides) -> TrainState:
    model = {"encoder.w": np.arange(6, dtype=np.float32).reshape(2, 3), "bn.num_batches_tracked": np.array(3)}
    optimizer = {"state": {0: {"step": np.array(2), "exp_avg": np.ones((2, 3), np.float32)}},
                 "param_groups": [{"lr": 1e-4, "betas": [0.9, 0.999]}]}
    return TrainState(step=5, epoch=0, batch=5, model=model, optimizer=optimizer, schedule={"last_step": 5},
                      rng_state={"state": 1}, config_json=TrainConfig().to_json(), model_config="{}")


def _write_state(path, state: TrainState, meta_overrides=None):
    tensors, meta = _flatten(state)
    meta.update(meta_overrides or {})
    save_safetensors(path, tensors, meta)


CHECKPOINT_SEEDS = [written_bytes(_write_state, _state(), suffix=".safetensors")]


def _check_state(state):
    assert isinstance(state, TrainState) and state.step == 5
    np.testing.assert_array_equal(state.model["encoder.w"], _state().model["encoder.w"])


@fuzz_settings(200)
@given(mutations(CHECKPOINT_SEEDS, max_edits=3))
def test_checkpoint_reads_or_raises(data):
    assert_reads_or_raises(read_checkpoint, data, allowed=(FormatError,), suffix=".safetensors", check=_check_state)


@fuzz_settings(150)
@given(st.dictionaries(st.sampled_from(["format", "step", "epoch", "batch", "schedule", "rng_state", "param_groups",
                                        "config", "model_config", "digest"]),
                       st.one_of(st.text(max_size=12), st.integers().map(str), st.just("{}"), st.just("[]")), max_size=4))
def test_checkpoint_metadata_is_checked(meta_overrides):
    data = written_bytes(_write_state, _state(), meta_overrides, suffix=".safetensors")
    result = assert_reads_or_raises(read_checkpoint, data, allowed=(FormatError,), suffix=".safetensors")
    if result is not None:
        assert isinstance(result, TrainState)
