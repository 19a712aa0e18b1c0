"""mipnet.serialization on the safetensors package: files interchange with ``safetensors.numpy`` both ways,
float16 loads, metadata is a dict of strings, and a bad file raises FormatError naming it."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from safetensors import safe_open
from safetensors.numpy import load_file, save_file

import mipnet
from mipnet.errors import FormatError
from mipnet.serialization import average_safetensors, load_safetensors, save_safetensors

TENSORS = {"w": np.arange(12, dtype=np.float32).reshape(3, 4), "h": np.array([0.5, -2.0, 65504.0], np.float16),
           "i": np.array([[1, -2]], np.int64), "m": np.array([True, False]), "s": np.array(3.0)}


def test_our_files_read_with_the_safetensors_package(tmp_path):
    path = tmp_path / "ours.safetensors"
    save_safetensors(path, TENSORS, {"note": "x", "n": 3})
    read = load_file(str(path))
    assert read.keys() == TENSORS.keys()
    for name, value in TENSORS.items():
        assert read[name].dtype == value.dtype and read[name].shape == value.shape
        np.testing.assert_array_equal(read[name], value)
    with safe_open(str(path), framework="np") as f:
        assert f.metadata() == {"note": "x", "n": "3"}


def test_the_packages_files_read_with_ours_float16_included(tmp_path):
    path = tmp_path / "theirs.safetensors"
    save_file(TENSORS, str(path), metadata={"format": "pt"})
    read, meta = load_safetensors(path)
    assert meta == {"format": "pt"} and all(isinstance(v, str) for v in meta.values())
    assert read["h"].dtype == np.float16 and read["s"].shape == ()
    for name, value in TENSORS.items():
        np.testing.assert_array_equal(read[name], value)
    read["w"][0, 0] = 7  # the arrays are the caller's own
    save_file({"x": np.ones(2, np.float32)}, str(path))
    assert load_safetensors(path)[1] == {}  # no metadata: an empty dict


def test_a_tensor_objects_numpy_and_a_big_endian_array_are_written(tmp_path):
    path = tmp_path / "t.safetensors"
    save_safetensors(path, {"t": mipnet.tensor(np.ones((2, 2), np.float32)), "be": np.arange(3, dtype=">f8"),
                            "strided": np.arange(20, dtype=np.int32).reshape(4, 5)[:, ::2]})
    read, _ = load_safetensors(path)
    np.testing.assert_array_equal(read["t"], np.ones((2, 2), np.float32))
    assert read["be"].dtype == np.float64 and read["be"].tolist() == [0.0, 1.0, 2.0]
    np.testing.assert_array_equal(read["strided"], np.arange(20, dtype=np.int32).reshape(4, 5)[:, ::2])
    with pytest.raises(FormatError, match="unsupported dtype"):
        save_safetensors(path, {"c": np.ones(2, np.complex64)})


def test_a_file_in_the_hand_written_layout_still_loads(tmp_path):
    """The layout the former writer produced: JSON in insertion order, padded with spaces to 8 bytes."""
    a, b = np.arange(3, dtype=np.float32), np.array([7], np.uint8)
    header = {"b": {"dtype": "U8", "shape": [1], "data_offsets": [0, 1]},
              "a": {"dtype": "F32", "shape": [3], "data_offsets": [1, 13]}, "__metadata__": {"k": "v"}}
    head = json.dumps(header, separators=(",", ":")).encode()
    head += b" " * (-len(head) % 8)
    (tmp_path / "old.safetensors").write_bytes(struct.pack("<Q", len(head)) + head + b.tobytes() + a.tobytes())
    read, meta = load_safetensors(tmp_path / "old.safetensors")
    assert meta == {"k": "v"}
    np.testing.assert_array_equal(read["a"], a)
    np.testing.assert_array_equal(read["b"], b)


@pytest.mark.parametrize("cut", [0, 5, 8, 20, -1])
def test_a_truncated_file_is_a_format_error_naming_it(tmp_path, cut):
    full = tmp_path / "full.safetensors"
    save_safetensors(full, TENSORS, {"k": "v"})
    data = full.read_bytes()
    bad = tmp_path / "cut.safetensors"
    bad.write_bytes(data[:cut] if cut >= 0 else data[:-3])
    with pytest.raises(FormatError) as error:
        load_safetensors(bad)
    assert str(bad) in str(error.value)


def test_a_dtype_mipnet_does_not_read_is_a_format_error(tmp_path):
    head = json.dumps({"x": {"dtype": "BF16", "shape": [2], "data_offsets": [0, 4]}}).encode()
    path = tmp_path / "bf16.safetensors"
    path.write_bytes(struct.pack("<Q", len(head)) + head + bytes(4))
    with pytest.raises(FormatError, match=r"bf16\.safetensors.*BF16"):
        load_safetensors(path)


def test_non_string_metadata_is_a_format_error(tmp_path):
    head = json.dumps({"__metadata__": {"step": 3}}).encode()
    path = tmp_path / "meta.safetensors"
    path.write_bytes(struct.pack("<Q", len(head)) + head)
    with pytest.raises(FormatError, match="meta.safetensors"):
        load_safetensors(path)


def test_a_missing_file_or_a_folder_is_an_os_error(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_safetensors(tmp_path / "missing.safetensors")
    with pytest.raises(IsADirectoryError):
        load_safetensors(tmp_path)


def test_average_reads_through_the_package(tmp_path):
    save_file({"w": np.full(2, 1.0, np.float32), "n": np.array([5], np.int64)}, str(tmp_path / "a.safetensors"))
    save_file({"w": np.full(2, 3.0, np.float32), "n": np.array([6], np.int64)}, str(tmp_path / "b.safetensors"))
    mean = average_safetensors([tmp_path / "a.safetensors", tmp_path / "b.safetensors"], [1, 3])
    np.testing.assert_allclose(mean["w"], [2.5, 2.5])
    assert mean["n"].tolist() == [5]
