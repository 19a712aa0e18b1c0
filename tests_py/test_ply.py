"""mipnet.stereo.io.write_ply writes PLY that the plyfile package reads back: binary little-endian, float32
x, y, z and optional uchar red, green, blue."""

import numpy as np
from plyfile import PlyData

from mipnet.stereo.io import write_ply


def test_plyfile_reads_back_points_and_colours(tmp_path):
    rng = np.random.default_rng(0)
    points = rng.normal(size=(50, 3)) * 10
    colors = rng.integers(0, 256, (50, 3), dtype=np.uint8)
    write_ply(tmp_path / "c.ply", points, colors)
    ply = PlyData.read(str(tmp_path / "c.ply"))
    assert not ply.text and ply.byte_order == "<"
    vertex = ply["vertex"]
    assert [(p.name, p.val_dtype) for p in vertex.properties] == [
        ("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    np.testing.assert_array_equal(np.stack([vertex[k] for k in "xyz"], 1), points.astype(np.float32))
    np.testing.assert_array_equal(np.stack([vertex[k] for k in ("red", "green", "blue")], 1), colors)


def test_without_colours_only_coordinates_and_the_header_is_the_classic_one(tmp_path):
    write_ply(tmp_path / "p.ply", [[1, 2, 3]])
    raw = (tmp_path / "p.ply").read_bytes()
    assert raw.startswith(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
                          b"property float y\nproperty float z\nend_header\n")
    assert raw.endswith(np.array([1, 2, 3], "<f4").tobytes())
    assert [p.name for p in PlyData.read(str(tmp_path / "p.ply"))["vertex"].properties] == ["x", "y", "z"]
