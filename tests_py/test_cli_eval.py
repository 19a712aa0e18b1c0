"""``mipnet eval``: a missing optional dependency is one line before any work (exit status 2), a dataset
of one pair is read before the model loads, and ``--out`` keeps the results as they come."""

import json
import sys

import numpy as np
import pytest

from mipnet.cli import main
from mipnet.cli import eval as eval_command
from helpers import require

TINY = ["--n", "2", "--size", "64", "96", "--iters", "1", "1"]


@pytest.fixture()
def no_model(monkeypatch):
    """Fails the test if the command loads the model (it should stop before any work)."""
    monkeypatch.setattr(eval_command, "load_model", lambda *a, **k: pytest.fail("the model was loaded"))


def _run(args, capsys):
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, [line for line in err.splitlines() if line]


def test_without_opencv_sgbm_is_one_line_before_any_work(monkeypatch, capsys, no_model):
    monkeypatch.setitem(sys.modules, "cv2", None)  # `import cv2` raises ImportError
    code, out, err = _run(["eval", "--dataset", "synthetic", *TINY], capsys)
    assert code == 2 and out == "" and len(err) == 1, err
    assert err[0].startswith("mipnet eval: error: --methods sgbm")
    assert "pip install opencv-python-headless" in err[0] and "--methods mipnet" in err[0]


def test_without_opencv_methods_mipnet_runs(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "cv2", None)
    code, out, _ = _run(["eval", "--dataset", "synthetic", "--methods", "mipnet", *TINY], capsys)
    assert code == 0 and "| MIPNet " in out and "SGBM" not in out


@pytest.mark.parametrize("methods", [[], ["--methods", "mipnet"]])
def test_motorcycle_without_scikit_image_is_one_line_before_any_work(methods, monkeypatch, capsys, no_model):
    if not methods:
        require("cv2")  # the default methods run SGBM too
    monkeypatch.setitem(sys.modules, "skimage", None)
    code, out, err = _run(["eval", "--dataset", "motorcycle", *methods, "--iters", "1", "1"], capsys)
    assert code == 2 and out == "" and len(err) == 1, err
    assert err[0] == "mipnet eval: error: --dataset motorcycle needs the skimage module: pip install scikit-image"


def test_a_one_pair_dataset_is_read_before_the_model_loads(tmp_path, capsys, no_model):
    require("tifffile")
    code, out, err = _run(["eval", "--dataset", "cones", "--root", str(tmp_path), "--methods", "mipnet"], capsys)
    assert code == 2 and out == "" and len(err) == 1, err
    assert err[0].startswith("mipnet eval: error: the cones pair is not in") and "mipnet fetch cones" in err[0]


def _lines(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_out_writes_each_pair_as_it_is_scored_then_the_table(tmp_path, capsys):
    require("cv2")
    path = tmp_path / "results.jsonl"
    code, out, _ = _run(["eval", "--dataset", "synthetic", *TINY, "--min-confidence", "0.5", "--out", str(path)],
                        capsys)
    assert code == 0
    lines = _lines(path)
    pairs = [line for line in lines if "summary" not in line]
    summary = {line["method"]: line for line in lines if "summary" in line}
    methods = ["MIPNet", "MIPNet (confidence >= 0.5)", "SGBM (full coverage)", "SGBM (covered)"]
    assert sorted(summary) == sorted(methods) and all(line["summary"] == "mean" for line in summary.values())
    for method in methods:
        rows = [line for line in pairs if line["method"] == method]
        assert [row["pair"] for row in rows] == [0, 1] and all(row["dataset"] == "synthetic" for row in rows)
        # the table's mean is the mean of the rows written per pair
        assert summary[method]["images"] == 2
        np.testing.assert_allclose(np.mean([row["epe"] for row in rows]), summary[method]["epe"], rtol=1e-6)
        assert f"| {method} " in out
    assert all(row["coverage"] == 100.0 for row in pairs if row["method"] == "MIPNet")


def test_out_keeps_the_pairs_scored_before_a_crash(tmp_path, monkeypatch, capsys):
    """SGBM breaking on its first pair (a bug, not a user error: the traceback propagates) leaves the
    MIPNet rows of every pair in the file."""
    require("cv2")
    import mipnet.stereo.baselines

    def broken(*args, **kwargs):
        raise RuntimeError("SGBM broke")

    monkeypatch.setattr(mipnet.stereo.baselines, "sgbm", broken)
    path = tmp_path / "results.jsonl"
    with pytest.raises(RuntimeError, match="SGBM broke"):
        main(["eval", "--dataset", "synthetic", *TINY, "--out", str(path)])
    lines = _lines(path)
    assert [(line["method"], line["pair"]) for line in lines] == [("MIPNet", 0), ("MIPNet", 1)]
    assert all(np.isfinite(line["epe"]) for line in lines)


def test_a_pair_that_cannot_be_read_is_reported_once(tmp_path, monkeypatch, capsys):
    """Two methods make two passes over the pairs; the unreadable pair is skipped once, not per pass."""
    require("cv2")
    from mipnet.data import registry

    opened = registry.open_dataset

    def with_a_broken_pair(*args, **kwargs):
        dataset = opened(*args, **kwargs)
        get = dataset.__getitem__

        class Broken(type(dataset)):
            def __getitem__(self, index):
                if index == 1:
                    raise FileNotFoundError(2, "No such file or directory", "pair1_left.png")
                return get(index)

        dataset.__class__ = Broken
        return dataset

    monkeypatch.setattr(registry, "open_dataset", with_a_broken_pair)
    code, out, err = _run(["eval", "--dataset", "synthetic", *TINY], capsys)
    assert code == 1
    assert sum("skipped" in line for line in err) == 1, err
    assert "mipnet eval: 1 of 2 pairs failed:" in err
    rows = [line for line in out.splitlines() if line.startswith(("| MIPNet", "| SGBM"))]
    assert len(rows) == 3 and all(line.rstrip(" |").endswith("1") for line in rows), rows
