"""ONNX export (``mipnet.export_onnx``, ``mipnet export --onnx``): the graph passes ``onnx.checker`` with standard
operators only, onnxruntime and OpenVINO run it and agree with ``MIPNet.forward`` on the bundled pair (mean
|difference| <= 1e-3 px) at two sizes and at the pair's own size, every architecture option and the opsets whose
operator signatures differ export, a dynamic-size graph runs any size, and bad input fails clearly without
leaving a file behind."""

import errno
import os
import sys

import numpy as np
import pytest
from PIL import Image

import mipnet
from mipnet.cli import main
from mipnet.errors import ArgumentError, DTypeError, ShapeError
from mipnet.export import export_onnx, initial_disparity
from helpers import require

onnx = require("onnx")
ort = require("onnxruntime")

#: the issue's agreement bound: mean |ONNX runtime - mipnet| over the pixels, in pixels
MEAN_PX = 1e-3
#: two small sizes (the first not a multiple of 16: the graph pads and crops) and few iterations keep CI fast
SIZES = [(56, 84), (96, 128)]
ITERS = (2, 2)


@pytest.fixture(scope="module")
def model():
    return mipnet.MIPNet.pretrained()


@pytest.fixture(scope="module")
def exported(model, tmp_path_factory):
    """size -> the path of the shipped weights exported at that size with ITERS (once per size)."""
    folder, paths = tmp_path_factory.mktemp("onnx"), {}

    def path(size):
        if size not in paths:
            paths[size] = str(folder / f"mipnet_{size[0]}x{size[1]}.onnx")
            export_onnx(model, paths[size], size=size, iters=ITERS)
        return paths[size]
    return path


def bundled(size=None):
    """The bundled pair as (1, 3, H, W) float32 batches, resized to ``size`` (H, W) with Pillow when given."""
    pair = mipnet.data.example_pair()
    images = [pair["left"], pair["right"]]
    if size is not None:
        images = [np.asarray(Image.fromarray(im).resize(size[::-1], Image.BILINEAR)) for im in images]
    return [np.ascontiguousarray(im.astype(np.float32).transpose(2, 0, 1)[None]) for im in images]


def run_onnxruntime(path, feeds):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    return ort.InferenceSession(path, options, providers=["CPUExecutionProvider"]).run(["disparity"], feeds)[0]


def run_openvino(path, feeds):
    ov = require("openvino")
    compiled = ov.Core().compile_model(path, "CPU", {"INFERENCE_PRECISION_HINT": "f32", "INFERENCE_NUM_THREADS": 2})
    return np.asarray(compiled(feeds)[compiled.output("disparity")])


def mean_difference(theirs, ours):
    """mean |theirs - ours| of an ONNX output (N, 1, H, W) and mipnet's disparity (N, H, W)."""
    assert theirs.shape == (ours.shape[0], 1) + ours.shape[1:] and theirs.dtype == np.float32
    return float(np.abs(theirs[:, 0].astype(np.float64) - ours).mean())


def test_the_graph_passes_the_checker_with_standard_operators_unrolled_and_canonical_names(model, exported):
    loaded = onnx.load(exported(SIZES[0]))
    onnx.checker.check_model(loaded, full_check=True)
    assert [(o.domain, o.version) for o in loaded.opset_import] == [("", 17)]
    ops = {node.op_type for node in loaded.graph.node}
    assert all(node.domain == "" for node in loaded.graph.node)
    assert "Gather" in ops and not ops & {"Loop", "Scan", "If"}  # the row warps; iterations unrolled
    # every sub-update of every iteration is in the graph: 2 iterations a level, IP then RLS
    steps = {tuple(node.name.split("/")[:2]) for node in loaded.graph.node if "/iter" in node.name}
    assert steps == {(level, f"iter{t}.update_{block}") for level, n in (("level16", ITERS[0]), ("level4", ITERS[1]))
                     for t in range(n) for block in ("ip", "rls")}
    dims = {v.name: [d.dim_value for d in v.type.tensor_type.shape.dim] for v in [*loaded.graph.input, *loaded.graph.output]}
    assert dims == {"left": [1, 3, 56, 84], "right": [1, 3, 56, 84], "disparity": [1, 1, 56, 84]}
    # every parameter the eval forward uses, under its canonical name; IP's mask head never runs in eval (each
    # level's mask comes from its last sub-update, RLS's)
    parameters = {k for k in model.state_dict() if not k.endswith("num_batches_tracked")
                  and not k.startswith("update_ip.mask_head.")}
    initializers = {i.name for i in loaded.graph.initializer}
    assert initializers & set(model.state_dict()) == parameters and "initial_disparity" in initializers
    state = model.state_dict()
    stored = {i.name: onnx.numpy_helper.to_array(i) for i in loaded.graph.initializer if i.name in parameters}
    assert all(np.array_equal(stored[k], state[k]) for k in parameters)


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("runtime", ["onnxruntime", "openvino"])
def test_runtimes_agree_with_mipnet_on_the_bundled_pair(model, exported, runtime, size):
    left, right = bundled(size)
    run = run_onnxruntime if runtime == "onnxruntime" else run_openvino
    theirs = run(exported(size), {"left": left, "right": right})
    assert mean_difference(theirs, model(left, right, iters=ITERS)) <= MEAN_PX


def test_onnxruntime_agrees_at_the_bundled_pairs_own_size_with_the_default_iterations(model, tmp_path):
    pair = mipnet.data.example_pair()
    left, right = bundled()
    path = str(tmp_path / "mipnet.onnx")
    export_onnx(model, path, size=left.shape[2:])  # (6, 6) iterations, seed 20: what model(left, right) runs
    theirs = run_onnxruntime(path, {"left": left, "right": right})
    assert mean_difference(theirs, model(pair["left"], pair["right"])[None]) <= MEAN_PX


def test_a_dynamic_graph_runs_any_size_and_batch_from_the_seeded_initial_disparity(model, tmp_path):
    path = str(tmp_path / "dynamic.onnx")
    proto = export_onnx(model, path, dynamic=True, iters=(2, 1))
    assert [d.dim_param for d in proto.graph.input[0].type.tensor_type.shape.dim] == ["batch", "", "height", "width"]
    assert [i.name for i in proto.graph.input] == ["left", "right", "disp_init"]
    left, right = bundled()
    for size, crops in (((56, 84), [(0, 0), (30, 17)]), ((64, 64), [(100, 200)])):
        # a batch of different crops of the bundled pair
        crop = lambda a: np.concatenate([a[:, :, y:y + size[0], x:x + size[1]] for y, x in crops])
        l, r = crop(left), crop(right)
        feeds = {"left": l, "right": r, "disp_init": initial_disparity(model, size, batch=len(crops))}
        assert mean_difference(run_onnxruntime(path, feeds), model(l, r, iters=(2, 1))) <= MEAN_PX


@pytest.mark.parametrize("opset, config", [
    (18, {}),                                                          # Reduce*/Split/Pad signatures of opset 18
    (20, {"vertical_constraint": False}),                              # GridSample's opset-20 mode name
    (17, {"vertical_constraint": False, "use_rls": False}),
    (17, {"use_aff": False, "use_ip": False, "rx": 2, "ry": 0}),
], ids=["opset18", "gridsample-opset20", "gridsample-ip-only", "no-aff-rls-only-rx2-ry0"])
def test_every_architecture_option_and_opset_exports(opset, config, tmp_path):
    mipnet.manual_seed(3)
    net = mipnet.MIPNet(**config).eval()
    path = str(tmp_path / "net.onnx")
    proto = export_onnx(net, path, size=(40, 72), iters=(1, 0), opset=opset, batch=2)  # n4 = 0: the 1/16 prediction
    ops = {node.op_type for node in proto.graph.node}
    assert ("GridSample" in ops) == (not net.config.vertical_constraint)
    left, right = bundled((40, 72))
    l, r = np.concatenate([left, right]), np.concatenate([right, left])
    assert mean_difference(run_onnxruntime(path, {"left": l, "right": r}), net(l, r, iters=(1, 0))) <= MEAN_PX


@pytest.mark.parametrize("kwargs, error, words", [
    ({"size": (16, 84)}, ShapeError, "at least 32"),
    ({"size": (56,)}, ShapeError, "(H, W)"),
    ({}, ArgumentError, "size=(H, W)"),
    ({"size": (56, 84), "dynamic": True}, ArgumentError, "not both"),
    ({"size": (56, 84), "iters": (0, 2)}, ArgumentError, "n16 >= 1"),
    ({"size": (56, 84), "opset": 16}, ArgumentError, "opset must be an integer from 17"),
    ({"size": (56, 84), "batch": 0}, ArgumentError, "batch must be a positive integer"),
    ({"dynamic": True, "disp_init_input": False}, ArgumentError, "needs the disp_init input"),
    ({"size": (56, 84), "seed": None}, ArgumentError, "seed must be an integer"),
])
def test_bad_arguments_raise_clear_errors_and_write_nothing(model, tmp_path, kwargs, error, words):
    with pytest.raises(error, match="export_onnx") as raised:
        export_onnx(model, tmp_path / "model.onnx", **kwargs)
    assert words in str(raised.value)
    assert os.listdir(tmp_path) == []


def test_a_model_that_is_not_a_float32_mipnet_is_refused(tmp_path):
    with pytest.raises(ArgumentError, match="must be a mipnet.MIPNet"):
        export_onnx(object(), tmp_path / "model.onnx", size=(56, 84))
    mipnet.manual_seed(0)
    with pytest.raises(DTypeError, match="float64"):
        export_onnx(mipnet.MIPNet().double(), tmp_path / "model.onnx", size=(56, 84))


def test_without_the_onnx_package_the_error_says_what_to_install(model, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnx", None)  # import onnx raises ImportError
    with pytest.raises(ArgumentError, match="pip install onnx"):
        export_onnx(model, tmp_path / "model.onnx", size=(56, 84))


def test_paths_that_cannot_be_written_fail_before_the_graph_is_built(model, tmp_path, monkeypatch):
    missing = tmp_path / "no" / "model.onnx"
    with pytest.raises(FileNotFoundError, match="does not exist") as raised:
        export_onnx(model, missing, size=(56, 84))
    assert raised.value.filename == str(missing)
    with pytest.raises(IsADirectoryError):
        export_onnx(model, tmp_path, size=(56, 84))
    monkeypatch.setattr(os, "access", lambda path, mode: False)  # a folder without write permission
    with pytest.raises(PermissionError, match="no permission"):
        export_onnx(model, tmp_path / "model.onnx", size=(56, 84))
    assert os.listdir(tmp_path) == []


def test_a_write_that_fails_leaves_the_old_file_and_no_temporary(model, tmp_path, monkeypatch):
    path = tmp_path / "model.onnx"
    path.write_text("the previous model")

    def disk_full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(os, "fsync", disk_full)  # the write fails after the bytes went to the temporary file
    with pytest.raises(OSError, match="No space left"):
        export_onnx(model, path, size=(56, 84), iters=(1, 0))
    assert path.read_text() == "the previous model" and os.listdir(tmp_path) == ["model.onnx"]


def test_the_top_level_name_is_the_export_function():
    assert mipnet.export_onnx is export_onnx


def test_cli_export_writes_a_graph_that_reproduces_the_shipped_model(model, tmp_path, capsys):
    path = tmp_path / "model.onnx"
    assert main(["export", "--onnx", str(path), "--size", "56", "84", "--iters", "1", "1"]) == 0
    out = capsys.readouterr().out
    assert f"wrote {path}" in out and "left 1x3x56x84" in out and "disparity 1x1x56x84" in out
    left, right = bundled((56, 84))
    theirs = run_onnxruntime(str(path), {"left": left, "right": right})
    assert mean_difference(theirs, model(left, right, iters=(1, 1))) <= MEAN_PX


def test_cli_dynamic_export_of_a_weights_file(tmp_path, capsys):
    mipnet.manual_seed(5)
    net = mipnet.MIPNet(use_aff=False).eval()
    weights = tmp_path / "w.safetensors"
    net.save(str(weights))
    path = tmp_path / "dynamic.onnx"
    assert main(["export", "--onnx", str(path), "--weights", str(weights), "--dynamic", "--iters", "1", "0"]) == 0
    assert "disp_init batchx1xheight16xwidth16" in capsys.readouterr().out
    left, right = bundled((48, 64))
    feeds = {"left": left, "right": right, "disp_init": initial_disparity(net, (48, 64))}
    assert mean_difference(run_onnxruntime(str(path), feeds), net(left, right, iters=(1, 0))) <= MEAN_PX


@pytest.mark.parametrize("args, words", [
    (["--weights", "{tmp}/nope.safetensors"], "nope.safetensors: No such file"),
    (["--size", "16", "16"], "below the minimum 32x32"),
    (["--size", "56", "84", "--dynamic"], "not allowed with"),
    (["--dynamic", "--batch", "2"], "--batch"),
    (["--opset", "16"], "opset must be an integer from 17"),
])
def test_cli_errors_are_one_line_with_status_2_and_no_file(tmp_path, capsys, args, words):
    path = tmp_path / "model.onnx"
    status = main(["export", "--onnx", str(path)] + [a.format(tmp=tmp_path) for a in args])
    err = capsys.readouterr().err
    assert status == 2 and words in err and len(err.strip().splitlines()) == 1
    assert not path.exists()


def test_cli_error_for_a_folder_that_does_not_exist(tmp_path, capsys):
    assert main(["export", "--onnx", str(tmp_path / "no" / "model.onnx")]) == 2
    assert "does not exist" in capsys.readouterr().err
