"""``mipnet infer`` over many pairs: outputs named after the scene folder when file names repeat (the
Middlebury / ETH3D layout), folders as -l, no output written twice, and pairs of one size batched."""

import os

import numpy as np
import pytest

import mipnet
from mipnet.cli import main
from mipnet.cli import infer as infer_command
from mipnet.data.synthetic import make_pair
from mipnet.stereo import io

ITERS = ["--iters", "1", "1"]


def _scene(folder, h, w, seed, names=("im0.png", "im1.png")):
    folder.mkdir(parents=True)
    pair = make_pair(h, w, seed=seed)
    io.write_image(folder / names[0], pair["left"])
    io.write_image(folder / names[1], pair["right"])


@pytest.fixture()
def middlebury(tmp_path):
    """Two scene folders with the same file names (and of different sizes: no batching here)."""
    _scene(tmp_path / "mb" / "Adirondack", 48, 64, seed=0)
    _scene(tmp_path / "mb" / "Jadeplant", 64, 80, seed=1)
    return tmp_path / "mb"


def _single_run(tmp_path, scene, name):
    out = tmp_path / f"single_{name}"
    assert main(["infer", "-l", str(scene / "im0.png"), "-r", str(scene / "im1.png"), "-o", str(out), *ITERS]) == 0
    return out / "im0"


def _outputs(out, name):
    return {suffix: (out / f"{name}_disp{suffix}").read_bytes() for suffix in (".npy", ".pfm", ".png")}


def test_repeated_file_names_are_written_per_scene_each_as_a_single_pair_run(middlebury, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["infer", "-l", str(middlebury / "*" / "im0.png"), "-r", str(middlebury / "*" / "im1.png"),
                 "-o", str(out), *ITERS]) == 0
    assert "wrote 2 disparity map(s)" in capsys.readouterr().out
    assert sorted(os.listdir(out)) == sorted(f"{scene}_disp{suffix}" for scene in ("Adirondack", "Jadeplant")
                                             for suffix in (".npy", ".pfm", ".png"))
    for scene in ("Adirondack", "Jadeplant"):
        single = _single_run(tmp_path, middlebury / scene, scene)
        # bitwise the files a run of that pair alone writes (named after its file there)
        assert _outputs(out, scene) == _outputs(single.parent, "im0")
    assert np.load(out / "Adirondack_disp.npy").shape == (48, 64)
    assert np.load(out / "Jadeplant_disp.npy").shape == (64, 80)


def test_folders_as_left_find_their_pair(middlebury, tmp_path, capsys):
    _scene(tmp_path / "lr" / "pier", 48, 64, seed=2, names=("left.png", "right.png"))
    many, one, same = tmp_path / "many", tmp_path / "one", tmp_path / "same"
    assert main(["infer", "-l", str(middlebury / "*"), "-o", str(many), *ITERS]) == 0
    assert main(["infer", "-l", str(tmp_path / "lr" / "pier"), "-o", str(one), *ITERS]) == 0
    assert main(["infer", "-l", str(middlebury / "Adirondack"), "-r", str(middlebury / "Adirondack"), "-o", str(same),
                 *ITERS]) == 0
    capsys.readouterr()
    by_files = tmp_path / "by_files"
    assert main(["infer", "-l", str(middlebury / "*" / "im0.png"), "-r", str(middlebury / "*" / "im1.png"),
                 "-o", str(by_files), *ITERS]) == 0
    for scene in ("Adirondack", "Jadeplant"):
        assert _outputs(many, scene) == _outputs(by_files, scene)
    assert _outputs(same, "Adirondack") == _outputs(by_files, "Adirondack")
    left, right = io.read_image(tmp_path / "lr" / "pier" / "left.png"), io.read_image(tmp_path / "lr" / "pier" / "right.png")
    np.testing.assert_array_equal(np.load(one / "pier_disp.npy"), mipnet.MIPNet.pretrained()(left, right, iters=(1, 1)))


def _one_error_line(capsys):
    err = [line for line in capsys.readouterr().err.splitlines() if line and not line.startswith("WARNING: ")]
    assert len(err) == 1, err
    return err[0]


def test_two_inputs_that_would_share_an_output_stop_the_run_before_any_work(tmp_path, capsys, monkeypatch):
    """a/x/im0.png and b/x/im0.png: both would be x_disp.*; one error naming both, nothing loaded or written."""
    _scene(tmp_path / "a" / "x", 48, 64, seed=0)
    _scene(tmp_path / "b" / "x", 48, 64, seed=1)
    monkeypatch.setattr(infer_command, "load_model", lambda *a, **k: pytest.fail("the model was loaded"))
    out = tmp_path / "out"
    assert main(["infer", "-l", str(tmp_path / "*" / "x" / "im0.png"), "-r", str(tmp_path / "*" / "x" / "im1.png"),
                 "-o", str(out), *ITERS]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("mipnet infer: error: ") and "x_disp" in line
    assert str(tmp_path / "a" / "x" / "im0.png") in line and str(tmp_path / "b" / "x" / "im0.png") in line
    assert not out.exists()


def test_a_folder_without_a_pair_is_one_error(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["infer", "-l", str(tmp_path / "empty"), "-o", str(tmp_path / "out"), *ITERS]) == 2
    line = _one_error_line(capsys)
    assert "empty: no stereo pair in this folder" in line and "im0.png" in line


class _Recording:
    """The shipped model, recording the batch size of every call."""

    def __init__(self, model):
        self.model, self.batches = model, []

    def __getattr__(self, name):
        return getattr(self.model, name)

    def __call__(self, left, right, **kwargs):
        self.batches.append(np.shape(left)[0] if np.ndim(left) == 4 else 1)
        return self.model(left, right, **kwargs)


@pytest.mark.parametrize("scale", [1.0, 0.75])
def test_pairs_of_one_size_run_batched_and_give_the_unbatched_disparities(tmp_path, monkeypatch, scale):
    """Five pairs: three of one size, then two of another. --batch-size 2 runs them as 2+1 and 2; the
    disparities equal those of --batch-size 1 within 1e-4 px. Not always bitwise: at some sizes a batch
    changes the order of float sums in the kernels (80x112: ~1e-5 px apart; 48x64: bitwise equal)."""
    sizes = [(80, 112)] * 3 + [(48, 64)] * 2
    for i, (h, w) in enumerate(sizes):
        pair = make_pair(h, w, seed=10 + i)
        io.write_image(tmp_path / f"p{i}_left.png", pair["left"])
        io.write_image(tmp_path / f"p{i}_right.png", pair["right"])
    runs = {}
    for batch_size in (2, 1):
        recording = _Recording(mipnet.MIPNet.pretrained())
        monkeypatch.setattr(infer_command, "load_model", lambda *a, **k: recording)
        out = tmp_path / f"b{batch_size}"
        assert main(["infer", "-l", str(tmp_path / "p*_left.png"), "-r", str(tmp_path / "p*_right.png"),
                     "-o", str(out), "--batch-size", str(batch_size), "--scale", str(scale), *ITERS]) == 0
        runs[batch_size] = [np.load(out / f"p{i}_left_disp.npy") for i in range(len(sizes))]
        assert recording.batches == ([2, 1, 2] if batch_size == 2 else [1] * 5)
    for batched, alone, (h, w) in zip(runs[2], runs[1], sizes):
        assert batched.shape == alone.shape == (h, w)
        np.testing.assert_allclose(batched, alone, rtol=0, atol=1e-4)


def test_a_batch_that_fails_runs_its_pairs_alone(tmp_path, monkeypatch):
    """A batch too large for the memory left runs pair by pair, with the same disparities."""
    for i in range(2):
        pair = make_pair(48, 64, seed=i)
        io.write_image(tmp_path / f"p{i}_left.png", pair["left"])
        io.write_image(tmp_path / f"p{i}_right.png", pair["right"])
    recording = _Recording(mipnet.MIPNet.pretrained())
    real_call = _Recording.__call__

    def refuse_batches(self, left, right, **kwargs):
        if np.ndim(left) == 4:
            self.batches.append("refused")
            raise MemoryError("a batch of two does not fit")
        return real_call(self, left, right, **kwargs)

    monkeypatch.setattr(_Recording, "__call__", refuse_batches)
    monkeypatch.setattr(infer_command, "load_model", lambda *a, **k: recording)
    out = tmp_path / "out"
    assert main(["infer", "-l", str(tmp_path / "p*_left.png"), "-r", str(tmp_path / "p*_right.png"),
                 "-o", str(out), *ITERS]) == 0
    assert recording.batches == ["refused", 1, 1]
    model = mipnet.MIPNet.pretrained()
    for i in range(2):
        left, right = io.read_image(tmp_path / f"p{i}_left.png"), io.read_image(tmp_path / f"p{i}_right.png")
        np.testing.assert_array_equal(np.load(out / f"p{i}_left_disp.npy"), model(left, right, iters=(1, 1)))
