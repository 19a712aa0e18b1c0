"""safetensors files in pure numpy (no pickle, no extra dependency).

Format: 8-byte little-endian header length, a JSON header mapping each name to
``{"dtype", "shape", "data_offsets": [begin, end]}`` (offsets into the byte buffer that follows)
plus an optional ``"__metadata__"`` dict of strings, then the raw little-endian tensor bytes.
"""

from __future__ import annotations

import json
import os
import struct
from typing import Any, Mapping

import numpy as np

from ._fileutil import atomic_write
from .errors import FormatError

_DTYPES = {"F32": np.float32, "F64": np.float64, "F16": np.float16, "I64": np.int64, "I32": np.int32,
           "I16": np.int16, "I8": np.int8, "U8": np.uint8, "BOOL": np.bool_}
_NAMES = {np.dtype(v): k for k, v in _DTYPES.items()}


def save_safetensors(path: str | os.PathLike, tensors: Mapping[str, Any], metadata: Mapping[str, str] | None = None) -> None:
    """Writes named arrays (and string metadata) to ``path`` atomically."""
    header: dict[str, Any] = {}
    blobs, offset = [], 0
    for name, value in tensors.items():
        a = np.asarray(value.numpy() if hasattr(value, "numpy") else value)
        if a.dtype not in _NAMES:
            raise FormatError(f"save_safetensors: {name} has unsupported dtype {a.dtype}")
        raw = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes(order="C")
        header[name] = {"dtype": _NAMES[a.dtype], "shape": list(a.shape), "data_offsets": [offset, offset + len(raw)]}
        blobs.append(raw)
        offset += len(raw)
    if metadata:
        header["__metadata__"] = {str(k): str(v) for k, v in metadata.items()}
    head = json.dumps(header, separators=(",", ":")).encode()
    head += b" " * (-len(head) % 8)  # the data section starts 8-byte aligned
    with atomic_write(path) as f:
        f.write(struct.pack("<Q", len(head)))
        f.write(head)
        for raw in blobs:
            f.write(raw)


def load_safetensors(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(name -> array, metadata) from a safetensors file; corrupt files raise ``FormatError`` naming it."""
    with open(path, "rb") as f:
        data = f.read()
    try:
        (n,) = struct.unpack("<Q", data[:8])
        if 8 + n > len(data):
            raise ValueError(f"header length {n} exceeds the file size {len(data)}")
        header = json.loads(data[8:8 + n])
        meta = header.pop("__metadata__", {}) or {}
        body = memoryview(data)[8 + n:]
        out = {}
        for name, info in header.items():
            begin, end = info["data_offsets"]
            dtype = np.dtype(_DTYPES[info["dtype"]]).newbyteorder("<")
            shape = tuple(info["shape"])
            if not 0 <= begin <= end <= len(body) or end - begin != int(np.prod(shape)) * dtype.itemsize:
                raise ValueError(f"tensor {name}: offsets {begin}..{end} do not fit shape {list(shape)} / file size")
            out[name] = np.frombuffer(body[begin:end], dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="))
        return out, dict(meta)
    except (struct.error, ValueError, KeyError, TypeError) as e:
        raise FormatError(f"{os.fspath(path)}: not a valid safetensors file ({e})") from None
