"""The command line's shape: one module a subcommand, a help string for every option, ``--version``,
the output folder's one long option (``--output`` unambiguous), and infer's ``--z-far``."""

import argparse
import importlib

import numpy as np
import pytest

import mipnet
from mipnet.cli import main
from mipnet.cli.app import build_parser
from mipnet.data.synthetic import make_pair
from mipnet.stereo import io

COMMANDS = ("infer", "eval", "train", "adapt", "info", "fetch", "export")


def _subparsers(parser):
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def test_each_subcommand_has_its_module_with_add_parser_and_run():
    parsers = _subparsers(build_parser())
    assert sorted(parsers) == sorted(COMMANDS)
    for command in COMMANDS:
        module = importlib.import_module(f"mipnet.cli.{command}")
        assert callable(module.add_parser) and callable(module.run)
        assert parsers[command].get_default("func") is module.run


def test_every_option_of_every_command_has_a_help_string():
    parser = build_parser()
    missing = []
    for name, sub in [("mipnet", parser), *_subparsers(parser).items()]:
        for action in sub._actions:
            if isinstance(action, argparse._SubParsersAction):
                continue
            if not action.help or action.help == argparse.SUPPRESS:
                missing.append(f"{name} {'/'.join(action.option_strings) or action.dest}")
    assert missing == []


@pytest.mark.parametrize("command", COMMANDS)
def test_help_prints_and_exits_0(command, capsys):
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0 and f"usage: mipnet {command}" in capsys.readouterr().out


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out == f"mipnet {mipnet.__version__}\n"


@pytest.mark.parametrize("spelling", ["-o", "--output-directory", "--output", "--output-dir"])
def test_the_output_folder_has_one_long_option_that_any_prefix_names(spelling):
    args = build_parser().parse_args(["infer", spelling, "somewhere"])
    assert args.output_directory == "somewhere"


def test_infer_output_writes_there(tmp_path):
    assert main(["infer", "--output", str(tmp_path), "--iters", "1", "1"]) == 0
    assert (tmp_path / "example_left_disp.npy").exists()


def test_z_far_leaves_the_far_points_out_of_the_cloud(tmp_path, capsys):
    pair = make_pair(48, 64, seed=0)
    io.write_image(tmp_path / "l.png", pair["left"])
    io.write_image(tmp_path / "r.png", pair["right"])
    calib = tmp_path / "K.txt"
    calib.write_text("300 0 32 0 300 24 0 0 1\n0.1\n")
    common = ["infer", "-l", str(tmp_path / "l.png"), "-r", str(tmp_path / "r.png"), "--iters", "1", "1",
              "--calib", str(calib)]
    assert main(common + ["-o", str(tmp_path / "all")]) == 0
    depth = np.load(tmp_path / "all" / "l_depth.npy")
    z_far = float(np.median(depth[np.isfinite(depth)]))
    assert main(common + ["-o", str(tmp_path / "near"), "--z-far", str(z_far)]) == 0

    def vertices(path):
        header = path.read_bytes().split(b"end_header")[0].decode()
        return int(next(line.split()[-1] for line in header.splitlines() if line.startswith("element vertex")))

    near, everything = vertices(tmp_path / "near" / "l_points.ply"), vertices(tmp_path / "all" / "l_points.ply")
    assert near == int((depth <= z_far).sum()) and 0 < near < everything
    capsys.readouterr()
    assert main(["infer", "--z-far", "5", "-o", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err.strip() == ("mipnet infer: error: --z-far needs --calib (the point cloud is "
                                               "written only with a calibration)")
