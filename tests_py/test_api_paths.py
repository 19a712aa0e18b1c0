"""torch's import paths work, and public modules export only their API."""

import importlib

import mipnet


def test_torch_import_paths():
    from mipnet.nn.utils import clip_grad_norm_
    from mipnet.optim.lr_scheduler import OneCycleLR
    from mipnet.utils.data import DataLoader, Dataset

    assert OneCycleLR is mipnet.optim.OneCycleLR
    assert clip_grad_norm_ is mipnet.optim.clip_grad_norm_
    assert Dataset is mipnet.data.Dataset and DataLoader is mipnet.data.DataLoader


def test_public_modules_export_only_their_api():
    for name in ("mipnet.optim", "mipnet.optim.lr_scheduler", "mipnet.nn", "mipnet.nn.utils", "mipnet.utils.data",
                 "mipnet.training", "mipnet.data", "mipnet.autograd", "mipnet.model.blocks", "mipnet.model.losses", "mipnet.model",
                 "mipnet.random", "mipnet.tensor", "mipnet.serialization", "mipnet.profiler", "mipnet.model.memory", "mipnet.model.pretrained"):
        module = importlib.import_module(name)
        assert "np" not in module.__all__ and "math" not in module.__all__, name
        for symbol in module.__all__:
            assert hasattr(module, symbol), (name, symbol)
