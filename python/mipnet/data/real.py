"""Real photographs with ground truth that ship inside packages, for evaluation only (never for
training or for choosing checkpoints and hyper-parameters).

* ``motorcycle``: the Middlebury 2014 "Motorcycle" pair (Scharstein et al., GCPR 2014), down-sampled
  4x (500x741, disparity 7-60 px, ~93% of pixels with ground truth), bundled in scikit-image
  (``skimage.data.stereo_motorcycle``; install ``scikit-image``, e.g. ``pip install ".[train]"``).
* ``cones``: the Middlebury 2003 "Cones" pair (Scharstein and Szeliski, CVPR 2003) at quarter size
  (375x450, disparity up to 55 px, 0 where unknown), in RGB, from the source package of CNES's
  ``pandora`` on PyPI (Apache-2.0; its notebooks' data). :func:`fetch_real` (``mipnet fetch cones``)
  downloads that package once (42 MB) through pip, from the package index pip is configured for (no
  download address is written here), checks its SHA-256 and keeps the three files the pair needs in
  ``real_data_dir()/cones``; reading them needs ``tifffile`` (a dependency of scikit-image).
"""

from __future__ import annotations

import hashlib
import io
import os
import subprocess
import sys
import tarfile
import tempfile
import urllib.request

import numpy as np

from ..utils.files import atomic_write
from ..errors import ArgumentError, FormatError
from .datasets import Dataset
from .synthetic import apply_water

__all__ = ["RealPairs", "REAL_SETS", "fetch_real", "real_data_dir"]

REAL_SETS = ("motorcycle", "cones")

#: the source package that holds the Cones pair (name, version, the SHA-256 of its .tar.gz as the index lists it),
#: the build backend its pyproject.toml names, and the members the Cones pair needs: left and right RGB
#: (float32 0-255) and the left disparity (float32)
_CONES_PACKAGE = ("pandora", "1.9.0", "b4b4a2b6028c34d498d89ef650dbefcfcdef7628e3e09d39d7d0bce52759a68d")
_CONES_BACKEND = "mesonpy"
_CONES_FILES = {"left_rgb.tif": "pandora-1.9.0/notebooks/data/left_rgb.tif",
                "right_rgb.tif": "pandora-1.9.0/notebooks/data/right_rgb.tif",
                "disparity.tif": "pandora-1.9.0/notebooks/data/Cones_LEFT_GT.tif"}


def real_data_dir() -> str:
    """Where fetched real pairs live: ``$MIPNET_REAL_DATA``, else ``~/.cache/mipnet/real``."""
    return os.environ.get("MIPNET_REAL_DATA") or os.path.join(os.path.expanduser("~"), ".cache", "mipnet", "real")


def fetch_real(name: str = "cones", root: str | None = None, url: str | None = None) -> str:
    """Download the real pair ``name`` (only ``cones`` needs it) into ``root/name`` and return that folder.

    The source package is found and downloaded by pip (``python -m pip download``, run by this Python), so
    the index, mirror, proxy, certificates and credentials of the user's pip configuration apply; its
    SHA-256 is checked here, and each extracted file is written atomically. Nothing is downloaded when the
    folder has the pair already.

    Parameters
    ----------
    name : str
        ``"cones"``.
    root : str, optional
        Default :func:`real_data_dir`.
    url : str, optional
        Another copy of the same source package instead of asking pip: a path, or a URL (``file://`` works);
        its SHA-256 must match.

    Raises
    ------
    ArgumentError
        An unknown name.
    FormatError
        A download whose SHA-256 differs, or a package without the expected files.
    OSError
        pip could not download the package (no index reachable, no such file on it, no pip), or ``url``
        cannot be read.
    """
    if name != "cones":
        raise ArgumentError(f"fetch_real: only 'cones' is fetched (motorcycle ships in scikit-image), got {name!r}")
    folder = os.path.join(root or real_data_dir(), name)
    if not _missing_cones_files(folder):
        return folder
    package, version, digest = _CONES_PACKAGE
    with tempfile.TemporaryDirectory(prefix="mipnet-fetch-") as scratch:
        if url:
            source, payload = url, _read_copy(url)
        else:
            path = _pip_download(package, version, scratch)
            source, payload = path, open(path, "rb").read()
    got = hashlib.sha256(payload).hexdigest()
    if got != digest:
        raise FormatError(f"fetch_real('cones'): {source} has SHA-256 {got}, expected {digest} "
                          f"({package} {version}'s source package)")
    os.makedirs(folder, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(payload), mode="r:gz") as archive:
        for target, member in _CONES_FILES.items():
            if member not in archive.getnames() or (data := archive.extractfile(member)) is None:
                raise FormatError(f"fetch_real('cones'): {member} is not in {source}")
            with atomic_write(os.path.join(folder, target)) as f:
                f.write(data.read())
    return folder


def _read_copy(url: str) -> bytes:
    """The bytes of a copy of the source package the user named: a URL (``scheme://``) or a path."""
    if "://" in url:
        with urllib.request.urlopen(url, timeout=120) as response:
            return response.read()
    with open(url, "rb") as f:
        return f.read()


#: A stand-in for the package's build backend. ``pip download`` saves a source package only after it has
#: prepared its metadata by running the backend the package names, which for pandora (meson-python) would
#: compile it. This backend reports the pinned name and version and builds nothing, so pip only finds,
#: downloads and saves the file.
_STAND_IN_BACKEND = """\
import os


def get_requires_for_build_wheel(config_settings=None):
    return []


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    info = os.path.join(metadata_directory, "{dist_info}")
    os.makedirs(info, exist_ok=True)
    with open(os.path.join(info, "METADATA"), "w") as f:
        f.write("Metadata-Version: 2.1\\nName: {name}\\nVersion: {version}\\n")
    return "{dist_info}"


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    raise RuntimeError("mipnet fetch only downloads this source package; it does not build it")
"""


def _pip_download(package: str, version: str, scratch: str) -> str:
    """``pip download`` of ``package==version``'s source package into ``scratch``, with the index pip is
    configured for (its config files, ``PIP_*`` variables); the path of the saved file. OSError naming pip's
    own error if it fails."""
    backends = os.path.join(scratch, "backend")
    os.makedirs(os.path.join(backends, _CONES_BACKEND))
    with open(os.path.join(backends, _CONES_BACKEND, "__init__.py"), "w") as f:
        f.write(_STAND_IN_BACKEND.format(name=package, version=version, dist_info=f"{package}-{version}.dist-info"))
    dest = os.path.join(scratch, "download")
    requirement = f"{package}=={version}"
    command = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", "--no-build-isolation",
               "--disable-pip-version-check", "--progress-bar", "off", "-d", dest, requirement]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [backends, os.environ.get("PYTHONPATH")]))}
    try:
        done = subprocess.run(command, capture_output=True, text=True, env=env, stdin=subprocess.DEVNULL)
    except OSError as error:
        raise OSError(f"fetch_real('cones'): cannot run pip ({error})") from error
    saved = sorted(os.listdir(dest)) if os.path.isdir(dest) else []
    if done.returncode != 0 or len(saved) != 1:
        lines = [line.strip() for line in (done.stderr or done.stdout).splitlines() if line.strip()]
        errors = [line for line in lines if line.lower().startswith("error")] or lines[-1:] or ["no output"]
        raise OSError(f"fetch_real('cones'): `python -m pip download {requirement}` (the source package, through "
                      f"pip's configured index) failed: {errors[0]}; with a copy of {package}-{version}.tar.gz, "
                      "pass it instead (mipnet fetch cones --source FILE)")
    return os.path.join(dest, saved[0])


def _missing_cones_files(folder: str) -> list[str]:
    """The files of the Cones pair that ``folder`` lacks."""
    return [f for f in _CONES_FILES if not os.path.isfile(os.path.join(folder, f))]


def _pair(left: np.ndarray, right: np.ndarray, disparity: np.ndarray) -> dict:
    """A real pair's sample: ground truth valid where finite and positive, 0 elsewhere."""
    valid = np.isfinite(disparity) & (disparity > 0)
    return {"left": left, "right": right, "disparity": np.where(valid, disparity, 0).astype(np.float32), "valid": valid}


def _motorcycle() -> dict:
    try:
        from skimage.data import stereo_motorcycle
    except ImportError:
        raise ArgumentError("the motorcycle pair ships in scikit-image: pip install scikit-image") from None
    return _pair(*stereo_motorcycle())


def _cones(root: str | None) -> dict:
    folder = os.path.join(root or real_data_dir(), "cones")
    missing = _missing_cones_files(folder)
    if missing:
        raise ArgumentError(f"the cones pair is not in {folder} (missing {missing}): fetch it once with "
                            "`mipnet fetch cones` (downloads the pandora source package from PyPI, 42 MB)")
    try:
        import tifffile
    except ImportError:
        raise ArgumentError("reading the cones pair needs tifffile: pip install tifffile") from None
    views = [tifffile.imread(os.path.join(folder, f)) for f in ("left_rgb.tif", "right_rgb.tif")]
    disparity = np.asarray(tifffile.imread(os.path.join(folder, "disparity.tif")), dtype=np.float32)
    if views[0].shape != views[1].shape or views[0].shape[:2] != disparity.shape or views[0].shape[2:] != (3,):
        raise FormatError(f"cones pair in {folder}: left {list(views[0].shape)}, right {list(views[1].shape)}, "
                          f"disparity {list(disparity.shape)}: expected (H, W, 3) twice and (H, W)")
    left, right = (np.clip(np.rint(v), 0, 255).astype(np.uint8) for v in views)
    return _pair(left, right, disparity)


class RealPairs(Dataset):
    """The real pairs of ``name`` (see :data:`REAL_SETS`), optionally under synthetic water
    (``underwater``: a preset name or ``"random"``, drawn with seed ``seed``). ``root``: where
    :func:`fetch_real` put the fetched pairs (default :func:`real_data_dir`).

    Shapes
    ------
    items: left, right (H, W, 3) uint8; disparity (H, W) float32 (0 where unknown); valid (H, W) bool.
    """

    def __init__(self, name: str = "motorcycle", underwater=None, seed: int = 1_000_000, root: str | None = None):
        if name not in REAL_SETS:
            raise ArgumentError(f"RealPairs: unknown set {name!r}; choose one of {list(REAL_SETS)}")
        self.name, self.underwater, self.seed, self.root = name, underwater, seed, root

    def __len__(self) -> int:
        return 1

    def __getitem__(self, index: int) -> dict:
        self._check_index(index)
        pair = _motorcycle() if self.name == "motorcycle" else _cones(self.root)
        label = apply_water(pair, self.underwater, self.seed)
        pair["meta"] = {"dataset": self.name, "index": 0, "underwater": label}
        return pair
