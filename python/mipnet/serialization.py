"""safetensors files in pure numpy (no pickle, no extra dependency).

Format: 8-byte little-endian header length, a JSON header mapping each name to
``{"dtype", "shape", "data_offsets": [begin, end]}`` (offsets into the byte buffer that follows)
plus an optional ``"__metadata__"`` dict of strings, then the raw little-endian tensor bytes.
"""

from __future__ import annotations

import json
import math
import os
import struct
from typing import Any, Mapping

import numpy as np

from .utils.files import atomic_write
from .errors import ArgumentError, FormatError

__all__ = ["save_safetensors", "load_safetensors", "average_safetensors"]

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


def average_safetensors(paths: list[str | os.PathLike], weights: list[float] | None = None) -> dict[str, np.ndarray]:
    """The weighted mean of several weights files of one network, tensor by tensor (a "model soup",
    Wortsman et al. 2022; SWA over the ends of learning-rate cycles, Izmailov et al. 2018): weights fine-tuned
    from a common ancestor share a basin, where their mean is often better than each.

    Floating tensors become sum_k w_k * t_k in float64, returned as float32 (``weights`` default equal, scaled
    to sum to one); other tensors are taken from the first file. Every file must hold the same names and shapes.
    """
    if not paths:
        raise ArgumentError("average_safetensors: no files given")
    w = np.ones(len(paths)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(paths),) or not np.all(np.isfinite(w)) or w.min() < 0 or w.sum() <= 0:
        raise ArgumentError(f"average_safetensors: need one non-negative weight per file ({len(paths)}), "
                          f"not all zero, got {weights}")
    w = w / w.sum()
    states = [load_safetensors(p)[0] for p in paths]
    first = states[0]
    for path, state in zip(paths[1:], states[1:]):
        if state.keys() != first.keys():
            raise FormatError(f"average_safetensors: {os.fspath(path)} holds other tensors than "
                              f"{os.fspath(paths[0])}: {sorted(state.keys() ^ first.keys())[:5]}")
        for name, value in state.items():
            if value.shape != first[name].shape:
                raise FormatError(f"average_safetensors: {name} is {value.shape} in {os.fspath(path)}, "
                                  f"{first[name].shape} in {os.fspath(paths[0])}")
    return {name: (sum(wk * s[name].astype(np.float64) for wk, s in zip(w, states)).astype(np.float32)
                   if value.dtype.kind == "f" else value)
            for name, value in first.items()}


#: The largest JSON header accepted (the reference implementation's limit, 100 MB).
MAX_HEADER_BYTES = 100_000_000


def load_safetensors(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(name -> array, metadata) from a safetensors file.

    Every header field is checked before any tensor is allocated: each tensor's byte range must lie
    in the file and hold exactly ``prod(shape) * itemsize`` bytes, so a header claiming more data
    than the file has is rejected. A corrupt or truncated file raises ``FormatError`` naming it.
    """
    with open(path, "rb") as f:
        data = f.read()
    try:
        header, body = _parse_header(data)
        meta = header.pop("__metadata__", None) or {}
        if not isinstance(meta, dict) or not all(isinstance(v, str) for v in meta.values()):
            raise ValueError("__metadata__ must map names to strings")
        return {name: _tensor(name, info, body) for name, info in header.items()}, dict(meta)
    except (ValueError, RecursionError) as e:  # json's errors (incl. UnicodeDecodeError) are ValueErrors
        raise FormatError(f"{os.fspath(path)}: not a valid safetensors file ({e})") from None


def _parse_header(data: bytes) -> tuple[dict, memoryview]:
    """The JSON header and the byte buffer after it; ValueError if they do not fit the file."""
    if len(data) < 8:
        raise ValueError(f"file of {len(data)} bytes, shorter than the 8-byte header length")
    (n,) = struct.unpack("<Q", data[:8])
    if n > min(len(data) - 8, MAX_HEADER_BYTES):
        raise ValueError(f"header length {n} exceeds the file size {len(data)} (or the limit {MAX_HEADER_BYTES})")
    header = json.loads(data[8:8 + n])
    if not isinstance(header, dict):
        raise ValueError(f"the header is a JSON {type(header).__name__}, not an object")
    return header, memoryview(data)[8 + n:]


def _is_index(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _tensor(name: str, info: Any, body: memoryview) -> np.ndarray:
    """One tensor of the header, checked against the byte buffer before it is read."""
    if not isinstance(info, dict) or not {"dtype", "shape", "data_offsets"} <= info.keys():
        raise ValueError(f"tensor {name}: entry must have dtype, shape and data_offsets")
    kind, shape, offsets = info["dtype"], info["shape"], info["data_offsets"]
    if not isinstance(kind, str) or kind not in _DTYPES:
        raise ValueError(f"tensor {name}: unsupported dtype {str(kind)[:20]!r} (supported: {', '.join(_DTYPES)})")
    if not isinstance(shape, list) or not all(_is_index(d) for d in shape):
        raise ValueError(f"tensor {name}: shape must be a list of non-negative integers, got {str(shape)[:60]}")
    if not isinstance(offsets, list) or len(offsets) != 2 or not all(_is_index(o) for o in offsets):
        raise ValueError(f"tensor {name}: data_offsets must be [begin, end], got {str(offsets)[:60]}")
    dtype = np.dtype(_DTYPES[kind]).newbyteorder("<")
    begin, end = offsets
    nbytes = math.prod(shape) * dtype.itemsize
    if not begin <= end <= len(body) or end - begin != nbytes:
        raise ValueError(f"tensor {name}: shape {shape} of {kind} needs {nbytes} bytes but data_offsets "
                         f"{begin}..{end} span {end - begin} of a {len(body)}-byte buffer")
    return np.frombuffer(body[begin:end], dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="))
