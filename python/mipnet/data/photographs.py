"""The real photographs that photo pairs (:mod:`mipnet.data.photo_pairs`) are made from.

Two kinds of source, both read from files already on the machine, never downloaded:

* the scene-like photographs that ship inside optional packages (``pip install 'mipnet[train]'``), listed
  with their licences in :data:`mipnet.data.textures.PHOTOS` — the ones of whole scenes or objects
  (:data:`SCENE_PHOTOS`), not the microscope, sky-survey or retina images that serve as textures only;
* every image in the folders named by the environment variable ``MIPNET_PHOTOS`` (folders separated by
  ``os.pathsep``; ``.png``, ``.jpg``, ``.jpeg``, ``.tif``, ``.tiff``, ``.bmp``, ``.webp``), for a user's own
  photographs or a larger licensed collection.

A stable hash of each photograph's name puts one in five into the held-out split: evaluation and validation
pairs are made from those only, training pairs from the rest, so validation measures photographs the network
never saw. Stereo partners and images with depth ground truth (Middlebury, KITTI, ...) are evaluation data:
they are never in this collection (a folder source must not hold them either).
"""

from __future__ import annotations

import functools
import os
import zlib
from pathlib import Path

from ..errors import ArgumentError
from . import textures

__all__ = ["SCENE_PHOTOS", "ENV_VARIABLE", "names", "load", "sources", "is_held_out"]

#: Names in :data:`mipnet.data.textures.PHOTOS` that show a scene or object (the others are textures only).
SCENE_PHOTOS = ("astronaut", "brick", "camera", "chelsea", "clock", "coffee", "coins", "grass", "gravel", "rocket",
                "china", "flower", "grace_hopper")
ENV_VARIABLE = "MIPNET_PHOTOS"
_EXTENSIONS = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp"}
_MAX_SIDE = 1600  # larger photographs are reduced to this on loading
_HELD_OUT_EVERY = 5


def is_held_out(name: str) -> bool:
    """Whether photograph ``name`` belongs to the held-out split (one in five, by a stable hash of the name)."""
    return zlib.crc32(name.encode()) % _HELD_OUT_EVERY == 0


def _folder_photos() -> dict[str, str]:
    """name -> path of every image in the ``MIPNET_PHOTOS`` folders (names: ``folder-name/file``)."""
    found = {}
    for folder in filter(None, os.environ.get(ENV_VARIABLE, "").split(os.pathsep)):
        root = Path(folder)
        if not root.is_dir():
            raise ArgumentError(f"{ENV_VARIABLE}: {folder} is not a folder")
        for path in sorted(root.rglob("*")):
            if path.suffix.lower() in _EXTENSIONS and path.is_file():
                found[f"{root.name}/{path.relative_to(root).as_posix()}"] = str(path)
    return found


@functools.lru_cache(maxsize=None)
def _catalogue(environment: str) -> dict[str, str]:
    """name -> path of every photograph available under ``environment`` (the value of ``MIPNET_PHOTOS``)."""
    entries = {entry[3]: entry for entry in textures.PHOTOS}
    found = {}
    for name in SCENE_PHOTOS:
        path = textures.photo_path(entries[name][1], entries[name][2])
        if path is not None:
            found[name] = path
    found.update(_folder_photos())
    return found


def _available() -> dict[str, str]:
    return _catalogue(os.environ.get(ENV_VARIABLE, ""))


def names(held_out: bool = False) -> list[str]:
    """The photographs of one split, sorted by name."""
    return sorted(name for name in _available() if is_held_out(name) == held_out)


def load(name: str):
    """Photograph ``name`` as an RGB ``PIL.Image`` (the longer side at most 1,600 px)."""
    path = _available().get(name)
    if path is None:
        raise ArgumentError(f"photographs: {name!r} is not an available photograph ({len(_available())} are)")
    return textures.read_photo(path, _MAX_SIDE)


def sources() -> list[str]:
    """What the collection holds here: the packages' photographs and the folders of ``MIPNET_PHOTOS``."""
    found = list(textures.photo_sources())
    found += [f"{ENV_VARIABLE}:{folder}" for folder in filter(None, os.environ.get(ENV_VARIABLE, "").split(os.pathsep))]
    return found
