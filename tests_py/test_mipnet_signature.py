"""``help(mipnet.MIPNet)`` shows the architecture keywords and a documented forward; ``MIPNet(**config)`` of a
saved config still builds the network."""

import dataclasses
import inspect
import json
import pydoc

import pytest

import mipnet
from mipnet.errors import ArgumentError, FormatError
from mipnet.model.config import MIPNetConfig


def test_init_has_a_keyword_signature_mirroring_the_config():
    params = inspect.signature(mipnet.MIPNet.__init__).parameters
    fields = dataclasses.fields(MIPNetConfig)
    assert [p for p in params if p != "self"] == [f.name for f in fields]
    for f in fields:
        assert params[f.name].kind is inspect.Parameter.KEYWORD_ONLY and params[f.name].default == f.default, f.name


def test_help_documents_every_parameter_and_forward():
    text = pydoc.render_doc(mipnet.MIPNet, renderer=pydoc.plaintext)
    for f in dataclasses.fields(MIPNetConfig):
        assert f"{f.name}:" in text and f.name in inspect.getdoc(mipnet.MIPNet.__init__)
    doc = inspect.getdoc(mipnet.MIPNet.forward)
    for section in ("Parameters", "Returns", "Raises", "iters", "disp_init", "scale", "(N, H, W)", "ShapeError",
                    "MemoryLimitError"):
        assert section in doc, section


def test_config_round_trips_and_bad_keywords_still_fail():
    config = MIPNetConfig(use_rls=False, rx=2, gamma_scale=8.0)
    model = mipnet.MIPNet(**json.loads(config.to_json()))
    assert model.config == config and not hasattr(model, "update_rls")
    with pytest.raises(TypeError):
        mipnet.MIPNet(unknown=1)
    with pytest.raises(TypeError):
        mipnet.MIPNet(True)
    with pytest.raises(ArgumentError):
        mipnet.MIPNet(use_ip=False, use_rls=False)


def test_load_rebuilds_the_saved_architecture_and_rejects_unknown_keys(tmp_path):
    model = mipnet.MIPNet(use_aff=False, ry=0)
    model.save(str(tmp_path / "w.safetensors"))
    assert mipnet.load(str(tmp_path / "w.safetensors")).config == model.config
    bad = mipnet.MIPNet()
    mipnet.serialization.save_safetensors(tmp_path / "bad.safetensors", bad.state_dict(),
                                          {"format": "mipnet", "config": json.dumps({"depth": 3})})
    with pytest.raises(FormatError, match="bad.safetensors"):
        mipnet.load(str(tmp_path / "bad.safetensors"))
