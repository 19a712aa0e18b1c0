"""Real photographs with ground truth that ship inside packages, for evaluation only (never for
training or for choosing checkpoints and hyper-parameters).

* ``motorcycle``: the Middlebury 2014 "Motorcycle" pair (Scharstein et al., GCPR 2014), down-sampled
  4x (500x741, disparity 7-60 px, ~93% of pixels with ground truth), bundled in scikit-image
  (``skimage.data.stereo_motorcycle``; install ``scikit-image``, e.g. ``pip install ".[train]"``).
* ``cones``: the Middlebury 2003 "Cones" pair (Scharstein and Szeliski, CVPR 2003) at quarter size
  (375x450, disparity up to 55 px, 0 where unknown), in RGB, from the source package of CNES's
  ``pandora`` on PyPI (Apache-2.0; its notebooks' data). :func:`fetch_real` (``mipnet fetch cones``)
  downloads that package once (42 MB, its SHA-256 checked) and keeps the three files the pair needs
  in ``real_data_dir()/cones``; reading them needs ``tifffile`` (a dependency of scikit-image).
"""

from __future__ import annotations

import hashlib
import io
import os
import tarfile
import urllib.request

import numpy as np

from ..utils.files import atomic_write
from ..errors import ArgumentError, FormatError
from .datasets import Dataset
from .synthetic import apply_water

__all__ = ["RealPairs", "REAL_SETS", "fetch_real", "real_data_dir"]

REAL_SETS = ("motorcycle", "cones")

#: where the pandora source package lies on PyPI, its SHA-256 (from PyPI's simple index), and the
#: members the Cones pair needs: left and right RGB (float32 0-255) and the left disparity (float32)
_CONES_SOURCE = (
    "https://files.pythonhosted.org/packages/9d/c3/0eff8324139f701df979c5f59ace2f44e732aa8d60799fd1c1c56f25f079/"
    "pandora-1.9.0.tar.gz",
    "b4b4a2b6028c34d498d89ef650dbefcfcdef7628e3e09d39d7d0bce52759a68d",
)
_CONES_FILES = {"left_rgb.tif": "pandora-1.9.0/notebooks/data/left_rgb.tif",
                "right_rgb.tif": "pandora-1.9.0/notebooks/data/right_rgb.tif",
                "disparity.tif": "pandora-1.9.0/notebooks/data/Cones_LEFT_GT.tif"}


def real_data_dir() -> str:
    """Where fetched real pairs live: ``$MIPNET_REAL_DATA``, else ``~/.cache/mipnet/real``."""
    return os.environ.get("MIPNET_REAL_DATA") or os.path.join(os.path.expanduser("~"), ".cache", "mipnet", "real")


def fetch_real(name: str = "cones", root: str | None = None, url: str | None = None) -> str:
    """Download the real pair ``name`` (only ``cones`` needs it) into ``root/name`` and return that folder.

    Parameters
    ----------
    name : str
        ``"cones"``.
    root : str, optional
        Default :func:`real_data_dir`.
    url : str, optional
        Another copy of the same source package (``file://`` works); its SHA-256 must match.

    Raises
    ------
    ArgumentError
        An unknown name.
    FormatError
        A download whose SHA-256 differs, or a package without the expected files.
    """
    if name != "cones":
        raise ArgumentError(f"fetch_real: only 'cones' is fetched (motorcycle ships in scikit-image), got {name!r}")
    folder = os.path.join(root or real_data_dir(), name)
    if not _missing_cones_files(folder):
        return folder
    source, digest = _CONES_SOURCE
    with urllib.request.urlopen(url or source, timeout=120) as response:
        payload = response.read()
    got = hashlib.sha256(payload).hexdigest()
    if got != digest:
        raise FormatError(f"fetch_real('cones'): {url or source} has SHA-256 {got}, expected {digest}")
    os.makedirs(folder, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(payload), mode="r:gz") as archive:
        for target, member in _CONES_FILES.items():
            if member not in archive.getnames() or (data := archive.extractfile(member)) is None:
                raise FormatError(f"fetch_real('cones'): {member} is not in {url or source}")
            with atomic_write(os.path.join(folder, target)) as f:
                f.write(data.read())
    return folder


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
