"""The command line: infer (files, globs, calibration outputs), eval, info; python -m mipnet."""

import os
import subprocess
import sys

import numpy as np
import pytest

import mipnet
from mipnet.stereo import io
from mipnet.cli import main
from mipnet.data.synthetic import make_pair
from helpers import require


@pytest.fixture()
def pairs_dir(tmp_path):
    for i in range(2):
        p = make_pair(48, 64, seed=i)
        io.write_image(tmp_path / f"scene{i}_left.png", p["left"])
        io.write_image(tmp_path / f"scene{i}_right.png", p["right"])
    return tmp_path


def test_infer_globs_write_every_output_with_calibration(pairs_dir, tmp_path, capsys):
    calib = tmp_path / "K.txt"
    calib.write_text("300 0 32 0 300 24 0 0 1\n0.1\n")
    out = tmp_path / "out"
    assert main(["infer", "-l", str(pairs_dir / "*_left.png"), "-r", str(pairs_dir / "*_right.png"),
                 "-o", str(out), "--iters", "1", "1", "--calib", str(calib)]) == 0
    assert "UNTRAINED" not in capsys.readouterr().err  # the shipped weights
    for i in range(2):
        stem = out / f"scene{i}_left"
        disp = np.load(f"{stem}_disp.npy")
        assert disp.shape == (48, 64) and disp.dtype == np.float32
        np.testing.assert_array_equal(io.read_pfm(f"{stem}_disp.pfm"), disp)
        assert io.read_image(f"{stem}_disp.png").shape == (48, 64, 3)
        depth = np.load(f"{stem}_depth.npy")
        ok = disp > 0
        np.testing.assert_allclose(depth[ok], 300 * 0.1 / disp[ok], rtol=1e-5)
        assert (out / f"scene{i}_left_points.ply").read_bytes().startswith(b"ply\n")
    assert not [f for f in os.listdir(out) if f.endswith(".tmp")]


def test_infer_without_images_runs_the_shipped_weights_on_the_bundled_example(tmp_path, capsys):
    assert main(["infer", "-o", str(tmp_path), "--iters", "1", "1"]) == 0
    disp = np.load(tmp_path / "example_left_disp.npy")
    from mipnet.data.example import EXAMPLE_LEFT, EXAMPLE_RIGHT

    expected = mipnet.MIPNet.pretrained()(io.read_image(EXAMPLE_LEFT), io.read_image(EXAMPLE_RIGHT), iters=(1, 1))
    np.testing.assert_array_equal(disp, expected)
    assert "UNTRAINED" not in capsys.readouterr().err


def test_infer_scale_writes_a_full_size_disparity_in_input_pixels(tmp_path):
    from mipnet.data.example import EXAMPLE_LEFT, EXAMPLE_RIGHT

    assert main(["infer", "-o", str(tmp_path), "--iters", "1", "1", "--scale", "0.5"]) == 0
    disp = np.load(tmp_path / "example_left_disp.npy")
    left = io.read_image(EXAMPLE_LEFT)
    expected = mipnet.MIPNet.pretrained()(left, io.read_image(EXAMPLE_RIGHT), iters=(1, 1), scale=0.5)
    assert disp.shape == left.shape[:2]
    np.testing.assert_array_equal(disp, expected)


def test_infer_min_confidence_marks_the_unbacked_pixels_invalid_everywhere(pairs_dir, tmp_path):
    calib = tmp_path / "K.txt"
    calib.write_text("300 0 32 0 300 24 0 0 1\n0.1\n")
    left, right = pairs_dir / "scene0_left.png", pairs_dir / "scene0_right.png"
    out = tmp_path / "out"
    assert main(["infer", "-l", str(left), "-r", str(right), "-o", str(out), "--iters", "1", "1",
                 "--calib", str(calib), "--min-confidence", "0.5"]) == 0
    raw = mipnet.MIPNet.pretrained()(io.read_image(left), io.read_image(right), iters=(1, 1))
    confidence = np.load(out / "scene0_left_conf.npy")
    np.testing.assert_array_equal(confidence, mipnet.match_confidence(io.read_image(left), io.read_image(right), raw))
    kept = confidence >= 0.5
    assert 0 < kept.sum() < kept.size
    disp = np.load(out / "scene0_left_disp.npy")
    np.testing.assert_array_equal(disp[kept], raw[kept])
    assert np.isinf(disp[~kept]).all() and np.isinf(io.read_pfm(out / "scene0_left_disp.pfm")[~kept]).all()
    assert np.isinf(np.load(out / "scene0_left_depth.npy")[~kept]).all()
    assert (io.read_image(out / "scene0_left_disp.png")[~kept] == 0).all()
    assert io.read_image(out / "scene0_left_conf.png").shape == (48, 64, 3)


def test_infer_confidence_alone_writes_the_map_and_keeps_every_pixel(pairs_dir, tmp_path):
    args = ["infer", "-l", str(pairs_dir / "scene0_left.png"), "-r", str(pairs_dir / "scene0_right.png"),
            "-o", str(tmp_path), "--iters", "1", "1"]
    assert main(args + ["--confidence"]) == 0
    assert (tmp_path / "scene0_left_conf.npy").exists() and np.isfinite(np.load(tmp_path / "scene0_left_disp.npy")).all()


def test_an_installation_without_weights_says_it_runs_untrained(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(mipnet.model.pretrained, "PRETRAINED_PATH", tmp_path / "absent.safetensors")
    assert main(["infer", "-o", str(tmp_path), "--iters", "1", "1"]) == 0
    assert "UNTRAINED" in capsys.readouterr().err


def test_shipped_weights_are_float16_with_their_provenance():
    from mipnet.serialization import load_safetensors

    tensors, meta = load_safetensors(mipnet.model.pretrained.PRETRAINED_PATH)
    assert {a.dtype for a in tensors.values() if a.dtype.kind == "f"} == {np.dtype(np.float16)}
    assert int(meta["step"]) > 0 and "generated scenes" in meta["trained"] and "validation" in meta
    model = mipnet.MIPNet.pretrained()
    assert not model.training and model.dtype == np.float32


def test_infer_with_saved_weights_matches_the_python_api(pairs_dir, tmp_path):
    mipnet.manual_seed(5)
    model = mipnet.MIPNet()
    model.save(str(tmp_path / "w.safetensors"))
    left = pairs_dir / "scene0_left.png"
    main(["infer", "-l", str(left), "-r", str(pairs_dir / "scene0_right.png"), "-o", str(tmp_path / "o"),
          "--weights", str(tmp_path / "w.safetensors"), "--iters", "1", "1"])
    expected = model.eval()(io.read_image(left), io.read_image(pairs_dir / "scene0_right.png"), iters=(1, 1))
    np.testing.assert_array_equal(np.load(tmp_path / "o" / "scene0_left_disp.npy"), expected)


def test_eval_prints_mipnet_and_sgbm_rows(capsys):
    require("cv2")
    assert main(["eval", "--dataset", "synthetic-underwater", "--preset", "low_light", "--n", "2",
                 "--size", "64", "96", "--iters", "1", "1"]) == 0
    out = capsys.readouterr().out
    assert "MIPNet " in out and "(untrained)" not in out and "SGBM (full coverage)" in out and "SGBM (covered)" in out


def test_eval_min_confidence_adds_a_covered_mipnet_row(capsys):
    assert main(["eval", "--dataset", "synthetic", "--n", "2", "--size", "64", "96", "--iters", "1", "1",
                 "--methods", "mipnet", "--min-confidence", "0.5"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| MIPNet")]
    assert len(rows) == 2 and "(confidence >= 0.5)" in rows[1]
    coverage = float(rows[1].split("|")[-3])
    assert 0 < coverage < 100 and float(rows[0].split("|")[-3]) == 100


def test_info_and_python_dash_m_entry_point():
    out = subprocess.run([sys.executable, "-m", "mipnet", "info"], capture_output=True, text=True, check=True).stdout
    assert "5,499,136" in out and "update_rls.gru" in out and "threads=" in out


def test_info_summarises_the_shipped_weights_and_history_prints_every_command(capsys):
    from mipnet.model import pretrained

    meta = pretrained.pretrained_info()
    assert main(["info"]) == 0
    short = capsys.readouterr().out
    assert f"  step: {meta['step']}" in short
    assert "validation (EPE px / bad-3 %):" in short
    air = meta["validation"]["air"]
    assert any(line.split() == ["air", f"{air['epe']:.3f}", "/", f"{air['bad3']:.1f}"] for line in short.splitlines())
    assert main(["info", "--history"]) == 0
    full = capsys.readouterr().out
    assert all(f"    {command}" in full for command in meta["commands"])
    assert meta["trained"] in full and len(full) > len(short)
