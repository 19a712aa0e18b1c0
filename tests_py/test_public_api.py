"""The public API: every documented name imports, every ``__all__`` resolves, the engine's torch paths exist,
and the names of mipnet 0.1 that moved still resolve (with a DeprecationWarning) to the modules that hold
them now."""

import importlib
import pkgutil
import warnings

import pytest

import mipnet

#: Names the README, docs/ and notebooks use, as a user writes them.
DOCUMENTED = [
    "mipnet.MIPNet", "mipnet.MIPNet.pretrained", "mipnet.MIPNetConfig", "mipnet.load", "mipnet.match_confidence",
    "mipnet.Tensor", "mipnet.tensor", "mipnet.no_grad", "mipnet.enable_grad", "mipnet.is_grad_enabled",
    "mipnet.manual_seed", "mipnet.set_num_threads", "mipnet.get_num_threads", "mipnet.__version__",
    "mipnet.Stream", "mipnet.rectify", "mipnet.export_onnx", "mipnet.data.make_sequence",
    "mipnet.distributed.infer_dataset", "mipnet.distributed.fit", "mipnet.model.MIPNet.forward_with_state",
    # the engine at torch's paths
    "mipnet.nn.Module", "mipnet.nn.Parameter", "mipnet.nn.Conv2d", "mipnet.nn.BatchNorm2d", "mipnet.nn.InstanceNorm2d",
    "mipnet.nn.Sequential", "mipnet.nn.init", "mipnet.nn.utils.clip_grad_norm_", "mipnet.nn.functional",
    "mipnet.optim.AdamW", "mipnet.optim.SGD", "mipnet.optim.lr_scheduler.OneCycleLR",
    "mipnet.utils.data.Dataset", "mipnet.utils.data.ConcatDataset", "mipnet.utils.data.DataLoader",
    "mipnet.utils.data.default_collate", "mipnet.autograd.Function", "mipnet.autograd.checkpoint",
    "mipnet.profiler.profile", "mipnet.serialization.load_safetensors", "mipnet.serialization.save_safetensors",
    "mipnet.errors.MipnetError", "mipnet.errors.ShapeError", "mipnet.errors.ArgumentError", "mipnet.errors.FormatError",
    "mipnet.errors.MemoryLimitError", "mipnet.ops.conv2d", "mipnet.ops.grid_sample",
    # the application
    "mipnet.model.losses.sequence_loss", "mipnet.model.memory.estimate", "mipnet.model.pretrained.pretrained_info",
    "mipnet.stereo.io.read_image", "mipnet.stereo.io.read_pfm", "mipnet.stereo.io.write_pfm",
    "mipnet.stereo.io.read_calib", "mipnet.stereo.io.write_ply", "mipnet.stereo.metrics.evaluate",
    "mipnet.stereo.metrics.aggregate", "mipnet.stereo.metrics.MetricAccumulator",
    "mipnet.stereo.evaluation.evaluate_method", "mipnet.stereo.geometry.disparity_to_depth",
    "mipnet.stereo.geometry.depth_to_points", "mipnet.stereo.viz.colorize", "mipnet.stereo.baselines.sgbm",
    "mipnet.underwater.degrade", "mipnet.underwater.texture_snr", "mipnet.underwater.random_water",
    "mipnet.underwater.PRESETS", "mipnet.underwater.WaterParams",
    "mipnet.data.SceneStereo", "mipnet.data.SyntheticStereo", "mipnet.data.make_pair", "mipnet.data.RealPairs",
    "mipnet.data.FolderPairs", "mipnet.data.SceneFlow", "mipnet.data.KITTI", "mipnet.data.example_pair",
    "mipnet.data.registry.open_dataset", "mipnet.data.registry.DATASETS",
    "mipnet.training.fit", "mipnet.training.resolve_config", "mipnet.training.TrainConfig",
    "mipnet.training.config.recipe_names", "mipnet.cli.main",
]


def resolve(dotted: str):
    """The object a dotted name names, importing modules along the way as a user's ``import`` would."""
    parts = dotted.split(".")
    obj = importlib.import_module(parts[0])
    for i, part in enumerate(parts[1:], start=1):
        if not hasattr(obj, part):
            obj = importlib.import_module(".".join(parts[: i + 1]))
        else:
            obj = getattr(obj, part)
    return obj


@pytest.mark.parametrize("name", DOCUMENTED)
def test_every_documented_name_resolves(name):
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        assert resolve(name) is not None


def _modules():
    yield mipnet
    for info in pkgutil.walk_packages(mipnet.__path__, "mipnet."):
        if not info.name.endswith("__main__"):
            yield importlib.import_module(info.name)


def test_every_name_in_every_all_exists():
    missing = [f"{m.__name__}.{n}" for m in _modules() for n in getattr(m, "__all__", ()) if not hasattr(m, n)]
    assert not missing


def test_modules_export_no_helper_imports():
    """``from mipnet.optim import *`` gives the optimisers, not numpy or typing."""
    for module in (mipnet.optim, mipnet.nn, mipnet.model, mipnet.stereo, mipnet.underwater, mipnet.data,
                   mipnet.training, mipnet.utils.data):
        assert hasattr(module, "__all__"), module.__name__
        assert not {"np", "math", "Any", "os", "sys"} & set(module.__all__), module.__name__


@pytest.mark.parametrize("old, new", sorted(mipnet._MOVED.items()))
def test_moved_names_still_resolve_with_a_deprecation_warning(old, new):
    with pytest.warns(DeprecationWarning, match=new):
        module = getattr(mipnet, old)
    assert module is importlib.import_module(new)


def test_an_unknown_attribute_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        mipnet.no_such_name  # noqa: B018
