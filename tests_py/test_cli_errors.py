"""The command line fails cleanly: each user error is one line ``mipnet <command>: error: ...`` naming
the file and the sizes, with exit status 2 (``--debug`` adds the traceback); a run over many pairs
goes on past a bad one, writes the good ones, lists the failures and exits with status 1."""

import os
import subprocess
import sys

import numpy as np
import pytest

from mipnet.stereo import io
from mipnet.cli import main
from mipnet.data.synthetic import make_pair
from helpers import require

H, W = 48, 64
ITERS = ["--iters", "1", "1"]


@pytest.fixture()
def files(tmp_path):
    """Good pairs scene0/scene1, a pair of different widths, a too-small pair, a truncated PNG, a
    bad calibration and a bad weights file, all in tmp_path."""
    for i in range(2):
        p = make_pair(H, W, seed=i)
        io.write_image(tmp_path / f"scene{i}_left.png", p["left"])
        io.write_image(tmp_path / f"scene{i}_right.png", p["right"])
    io.write_image(tmp_path / "wide_right.png", make_pair(H, W + 6, seed=2)["right"])
    io.write_image(tmp_path / "tiny_left.png", np.zeros((20, 24, 3), np.uint8))
    io.write_image(tmp_path / "tiny_right.png", np.zeros((20, 24, 3), np.uint8))
    good = (tmp_path / "scene0_left.png").read_bytes()
    (tmp_path / "truncated.png").write_bytes(good[: len(good) // 2])
    (tmp_path / "bad_calib.txt").write_text("cam0=[300 0 32; 0 300 24]\nbaseline=100\n")
    (tmp_path / "bad.safetensors").write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{not json at all")
    return tmp_path


def run(args, capsys):
    """(exit status, stdout, stderr lines) of ``mipnet.cli.main(args)``."""
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, [line for line in err.splitlines() if line and not line.startswith("WARNING: ")]


def infer(files, left, right, *extra):
    return ["infer", "-l", files / left, "-r", files / right, "-o", files / "out", *ITERS, *extra]


# each case: (command line, the command, texts the one error line must contain)
CASES = {
    "missing file": (lambda f: infer(f, "nope.png", "scene0_right.png"), "infer", ["nope.png", "No such file"]),
    "glob matching nothing": (lambda f: infer(f, "*_nothing.png", "*_right.png"), "infer", ["*_nothing.png", "no file matches"]),
    "a directory": (lambda f: ["infer", "-l", f, "-r", f / "scene0_right.png", "-o", f / "out"], "infer", ["not a file"]),
    "unpaired globs": (lambda f: infer(f, "scene*_left.png", "scene0_right.png"), "infer",
                       ["2 left images", "1 right images"]),
    "only --left": (lambda f: ["infer", "-l", f / "scene0_left.png"], "infer", ["both -l/--left and -r/--right"]),
    "different widths": (lambda f: infer(f, "scene1_left.png", "wide_right.png"), "infer",
                         ["scene1_left.png is 48x64", "wide_right.png is 48x70"]),
    "too small": (lambda f: infer(f, "tiny_left.png", "tiny_right.png"), "infer", ["tiny_left.png is 20x24", "32x32"]),
    "truncated image": (lambda f: infer(f, "truncated.png", "scene0_right.png"), "infer",
                        ["truncated.png", "cannot decode image", "bytes"]),
    "bad calibration": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--calib", f / "bad_calib.txt"),
                        "infer", ["bad_calib.txt", "cam0 must be a 3x3 matrix, got 6 numbers"]),
    "missing calibration": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--calib", f / "K.txt"),
                            "infer", ["K.txt", "No such file"]),
    "bad weights": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--weights", f / "bad.safetensors"),
                    "infer", ["bad.safetensors", "not a valid safetensors file"]),
    "unwritable output": (lambda f: [*infer(f, "scene0_left.png", "scene0_right.png")[:5], "-o", f / "scene0_left.png" / "x",
                                     *ITERS], "infer", ["scene0_left.png"]),
    "bad --iters": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--iters", "0", "1"), "infer",
                    ["--iters", "N16 >= 1", "0 1"]),
    "bad --scale": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--scale", "0"), "infer",
                    ["--scale", "positive number, got 0"]),
    "--scale too small": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--scale", "0.01"), "infer",
                          ["scale 0.01", "smaller than 32x32"]),
    "bad --min-confidence": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--min-confidence", "1.5"), "infer",
                             ["--min-confidence", "must be in (0, 1], got 1.5"]),
    "bad --threads": (lambda f: ["--threads", "0", "info"], None, ["--threads", "positive integer, got 0"]),
    "unknown option": (lambda f: ["info", "--bogus"], "info", ["unrecognized arguments: --bogus"]),
    "non-integer": (lambda f: ["info", "--batch", "two"], "info", ["--batch", "'two'"]),
    "bad colour range": (lambda f: infer(f, "scene0_left.png", "scene0_right.png", "--vmin", "5", "--vmax", "1"), "infer",
                         ["--vmin 5.0 must be below --vmax 1.0"]),
    "eval without --root": (lambda f: ["eval", "--dataset", "kitti2015"], "eval", ["--dataset kitti2015 needs --root"]),
    "eval empty root": (lambda f: ["eval", "--dataset", "kitti2015", "--root", f], "eval", ["no stereo pairs found"]),
    "eval bad --methods": (lambda f: ["eval", "--dataset", "synthetic", "--methods", "sgbm,magic"], "eval",
                           ["--methods 'sgbm,magic'"]),
    "eval too small": (lambda f: ["eval", "--dataset", "synthetic", "--size", "16", "16"], "eval", ["16x16", "32x32"]),
    "info too small": (lambda f: ["info", "--size", "8", "1000"], "info", ["8x1000"]),
    "train without --out": (lambda f: ["train"], "train", ["--out DIR"]),
    "train bad config": (lambda f: ["train", "--out", f / "run", "--config", f / "bad_calib.txt"], "train",
                         ["bad_calib.txt", "TOML"]),
}


@pytest.mark.parametrize("case", CASES)
def test_a_user_error_is_one_line_with_status_2(case, files, capsys):
    make_args, command, texts = CASES[case]
    code, out, err = run(make_args(files), capsys)
    prefix = f"mipnet {command}: error: " if command else "mipnet: error: "
    assert code == 2, f"exit status {code}, stderr {err}"
    assert len(err) == 1, f"expected one line, got {err}"
    assert err[0].startswith(prefix), err[0]
    for text in texts:
        assert text in err[0], f"{text!r} not in {err[0]!r}"


def test_memory_limit_is_a_clean_error_naming_the_estimate_and_the_limit(files, capsys, monkeypatch):
    monkeypatch.setenv("MIPNET_MEMORY_LIMIT", "64M")
    code, _, err = run(infer(files, "scene0_left.png", "scene0_right.png"), capsys)
    assert code == 2 and len(err) == 1, err
    assert "scene0_left.png" in err[0] and "MiB more memory" in err[0] and "MIPNET_MEMORY_LIMIT=64M" in err[0]


def test_debug_prints_the_traceback_as_well(files, capsys):
    for args in (["--debug", *infer(files, "scene1_left.png", "wide_right.png")],
                 [*infer(files, "scene1_left.png", "wide_right.png"), "--debug"]):
        assert main([str(a) for a in args]) == 2
        err = capsys.readouterr().err
        assert "Traceback (most recent call last)" in err and "ShapeError" in err
        assert err.rstrip().splitlines()[-1].startswith("mipnet infer: error: ")


def test_a_run_over_many_pairs_skips_bad_pairs_and_lists_them(files, capsys):
    """Four pairs: two good, one of different sizes, one truncated. The good ones are written in full,
    the bad ones listed at the end, exit status 1, no temporary file left."""
    os.replace(files / "wide_right.png", files / "scene2_right.png")
    io.write_image(files / "scene2_left.png", make_pair(H, W, seed=2)["left"])
    os.replace(files / "truncated.png", files / "scene3_left.png")
    io.write_image(files / "scene3_right.png", make_pair(H, W, seed=3)["right"])
    code, out, err = run(["infer", "-l", files / "scene*_left.png", "-r", files / "scene*_right.png",
                          "-o", files / "out", *ITERS], capsys)
    assert code == 1
    assert "wrote 2 disparity map(s)" in out
    for i in (0, 1):
        disp = np.load(files / "out" / f"scene{i}_left_disp.npy")
        np.testing.assert_array_equal(io.read_pfm(files / "out" / f"scene{i}_left_disp.pfm"), disp)
        assert io.read_image(files / "out" / f"scene{i}_left_disp.png").shape == (H, W, 3)
    assert not any(name.startswith(("scene2", "scene3")) for name in os.listdir(files / "out"))
    assert not [name for name in os.listdir(files / "out") if name.endswith(".tmp")]
    summary = err.index("mipnet infer: 2 of 4 pairs failed:")
    listed = err[summary + 1:]
    assert len(listed) == 2
    assert "scene2_left.png is 48x64" in listed[0] and "scene2_right.png is 48x70" in listed[0]
    assert "scene3_left.png" in listed[1] and "cannot decode image" in listed[1]


def test_eval_skips_an_unreadable_pair_and_scores_the_others(files, capsys):
    """A KITTI-layout folder of three pairs, one with a corrupt disparity file: the table covers two
    images, the corrupt file is listed, exit status 1."""
    require("cv2")
    root = files / "kitti"
    for sub in ("image_2", "image_3", "disp_occ_0"):
        (root / "training" / sub).mkdir(parents=True)
    for i in range(3):
        p = make_pair(H, W, seed=i)
        name = f"00000{i}_10.png"
        io.write_image(root / "training" / "image_2" / name, p["left"])
        io.write_image(root / "training" / "image_3" / name, p["right"])
        io.write_kitti_disparity(root / "training" / "disp_occ_0" / name, p["disparity"])
    (root / "training" / "disp_occ_0" / "000001_10.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    code, out, err = run(["eval", "--dataset", "kitti2015", "--root", root, *ITERS], capsys)
    assert code == 1
    rows = [line for line in out.splitlines() if line.startswith("| MIPNet") or line.startswith("| SGBM")]
    assert len(rows) == 3 and all(line.rstrip(" |").endswith("2") for line in rows), rows
    assert "mipnet eval: 1 of 3 pairs failed:" in err
    assert sum("mipnet eval: skipped" in line for line in err) == 1, err  # once, not once per method
    assert any("disp_occ_0/000001_10.png" in line and "cannot decode image" in line for line in err)


def test_a_subcommand_added_later_gets_the_same_error_handling(files, capsys, monkeypatch):
    """The handling lives in main(), so a subcommand registered in build_parser (as `train` will be)
    has --debug, the one-line errors and status 2 without code of its own."""
    import mipnet.cli.app as cli

    build = cli.build_parser

    def with_extra_command():
        parser = build()
        sub = next(a for a in parser._actions if a.dest == "command")
        extra = sub.add_parser("extra")
        extra.add_argument("--path", required=True)
        extra.set_defaults(func=lambda args: io.read_pfm(args.path))
        return parser

    monkeypatch.setattr(cli, "build_parser", with_extra_command)
    code, _, err = run(["extra", "--path", files / "scene0_left.png"], capsys)
    assert code == 2 and len(err) == 1 and err[0].startswith("mipnet extra: error: ") and "not a PFM file" in err[0]
    code, _, err = run(["extra"], capsys)
    assert code == 2 and err == ["mipnet extra: error: the following arguments are required: --path (see mipnet extra --help)"]
    assert main(["extra", "--path", str(files / "nope.pfm"), "--debug"]) == 2
    assert "Traceback" in capsys.readouterr().err


def test_the_installed_command_prints_one_line_and_exits_2(files):
    """The same through a real process (python -m mipnet), as a user's shell sees it."""
    proc = subprocess.run([sys.executable, "-m", "mipnet", *map(str, infer(files, "scene1_left.png", "wide_right.png"))],
                          capture_output=True, text=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert proc.returncode == 2
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("mipnet infer: error: "), lines
    assert f"{files / 'scene1_left.png'} is 48x64" in lines[0] and f"{files / 'wide_right.png'} is 48x70" in lines[0]
