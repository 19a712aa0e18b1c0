"""safetensors files, through the ``safetensors`` package's numpy API.

Writing serialises with :func:`safetensors.numpy.save` and puts the bytes in place atomically
(:func:`mipnet.utils.files.atomic_write`); reading goes through :func:`safetensors.safe_open`, which
checks the whole header against the file (every byte range inside the buffer and exactly
``prod(shape) * itemsize`` long, the ranges covering it without gaps, string-only metadata, a
header of at most 100 MB) before a tensor is read. A corrupt or truncated file raises
:class:`mipnet.errors.FormatError` naming it and what its header claims.
"""

from __future__ import annotations

import json
import os
import struct
from typing import Any, Mapping

import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save as _serialize

from .utils.files import atomic_write
from .errors import ArgumentError, FormatError

__all__ = ["save_safetensors", "load_safetensors", "average_safetensors"]

# The dtypes mipnet writes and reads (the format has more: BF16, F8, unsigned wider than 8 bits...).
_DTYPES = {"F32": np.float32, "F64": np.float64, "F16": np.float16, "I64": np.int64, "I32": np.int32,
           "I16": np.int16, "I8": np.int8, "U8": np.uint8, "BOOL": np.bool_}
_NAMES = {np.dtype(v): k for k, v in _DTYPES.items()}


def save_safetensors(path: str | os.PathLike, tensors: Mapping[str, Any], metadata: Mapping[str, str] | None = None) -> None:
    """Writes named arrays (and string metadata) to ``path`` atomically."""
    arrays = {}
    for name, value in tensors.items():
        a = np.asarray(value.numpy() if hasattr(value, "numpy") else value)
        native = a.dtype.newbyteorder("=")
        if native not in _NAMES:
            raise FormatError(f"save_safetensors: {name} has unsupported dtype {a.dtype}")
        # safetensors reads each array's buffer as it is: C order, native (it swaps big-endian ones itself)
        arrays[name] = a if a.flags.c_contiguous else a.copy(order="C")  # (np.ascontiguousarray makes 0-d 1-d)
    meta = {str(k): str(v) for k, v in metadata.items()} if metadata else None
    try:
        data = _serialize(arrays, metadata=meta)
    except SafetensorError as e:
        raise FormatError(f"save_safetensors: {os.fspath(path)}: {e}") from None
    with atomic_write(path) as f:
        f.write(data)


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


#: The largest JSON header accepted (the safetensors package's limit, 100 MB).
MAX_HEADER_BYTES = 100_000_000


def load_safetensors(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(name -> array, metadata) from a safetensors file.

    The ``safetensors`` package checks every header field before any tensor is read: each tensor's byte
    range must lie in the file and hold exactly ``prod(shape) * itemsize`` bytes, so a header claiming more
    data than the file has is rejected. A corrupt or truncated file, or a tensor of a dtype mipnet does not
    read (see ``_DTYPES``), raises ``FormatError`` naming the file; a file that cannot be opened raises the
    usual ``OSError``.
    """
    name = os.fspath(path)
    with open(name, "rb"):  # FileNotFoundError, IsADirectoryError, PermissionError as for any file
        pass
    try:
        with safe_open(name, framework="np") as f:
            keys = f.keys()
            for key in keys:
                kind = f.get_slice(key).get_dtype()
                if kind not in _DTYPES:
                    raise FormatError(f"{name}: not a valid safetensors file (tensor {key}: unsupported dtype "
                                      f"{kind!r}; supported: {', '.join(_DTYPES)})")
            meta = f.metadata() or {}
            tensors = {key: f.get_tensor(key) for key in keys}
    except SafetensorError as e:
        raise FormatError(f"{name}: not a valid safetensors file ({e}{_claims(name)})") from None
    return tensors, dict(meta)


def _claims(path: str) -> str:
    """What the header of a file the safetensors package refused claims (the header length, each tensor's
    dtype, shape and byte range, the data bytes there are), for the error message; "" if it cannot be told."""
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size < 8:
                return f": a file of {size} bytes, shorter than the 8-byte header length"
            (n,) = struct.unpack("<Q", f.read(8))
            if n > min(size - 8, MAX_HEADER_BYTES):
                return f": header length {n} exceeds the file size {size} (or the limit {MAX_HEADER_BYTES})"
            header = json.loads(f.read(n))
    except (OSError, ValueError, RecursionError):  # json's errors (incl. UnicodeDecodeError) are ValueErrors
        return ""
    if not isinstance(header, dict):
        return ""
    entries = [f"{key} {info.get('dtype')!s:.20} shape {info.get('shape')!s:.60} at {info.get('data_offsets')!s:.60}"
               for key, info in header.items() if key != "__metadata__" and isinstance(info, dict)]
    more = f" and {len(entries) - 3} more" if len(entries) > 3 else ""
    return f"; the header claims {'; '.join(entries[:3]) or 'no tensor'}{more} in {size - 8 - n} data bytes"
