"""The weights that ship inside the package: ``assets/mipnet_pretrained.safetensors``.

Float16 safetensors (upcast to float32 on load) trained by mipnet itself on its generated scenes,
on a CPU (``docs/training.md``). Its metadata says what it was trained on: the data and generator
version, steps, crop, batch, iterations, the commands, the package version and the validation table.
``export_pretrained`` writes such a file from a run's weights.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..serialization import load_safetensors, save_safetensors

PRETRAINED_PATH = Path(__file__).resolve().parents[1] / "assets" / "mipnet_pretrained.safetensors"

__all__ = ["PRETRAINED_PATH", "available", "pretrained_info", "decode_metadata", "export_pretrained"]


def available() -> bool:
    """Whether this installation ships trained weights."""
    return PRETRAINED_PATH.is_file()


def pretrained_info() -> dict:
    """The shipped file's metadata, JSON values decoded (empty without shipped weights)."""
    if not available():
        return {}
    return decode_metadata(load_safetensors(PRETRAINED_PATH)[1])


def decode_metadata(meta: dict) -> dict:
    """A safetensors header's metadata (strings) with the JSON-encoded values decoded."""
    out = {}
    for key, value in meta.items():
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def export_pretrained(weights: str, path: str | os.PathLike = PRETRAINED_PATH, tensors: dict | None = None,
                      **metadata) -> str:
    """Writes ``weights`` (a run's ``best.safetensors``) as float16 with its metadata plus ``metadata``
    (JSON-encoded unless strings); returns the path. ``tensors``: write these instead of the file's own (an
    average of several files), still with the file's metadata. Values outside float16's range are an error."""
    own, meta = load_safetensors(weights)
    tensors = own if tensors is None else tensors
    half = {}
    for name, value in tensors.items():
        if value.dtype.kind == "f":
            if np.abs(value).max(initial=0.0) > np.finfo(np.float16).max:
                raise FormatError(f"export_pretrained: {name} exceeds the float16 range")
            half[name] = value.astype(np.float16)
        else:
            half[name] = value
    meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()})
    save_safetensors(path, half, meta)
    return os.fspath(path)
