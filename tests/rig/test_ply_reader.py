"""`--ply` output read back by an independent PLY reader (the `plyfile` package), as common tools would read it."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData

from reconstruction.io import write_ply


def _points(n: int, seed: int = 7) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-300, -200, 400], [300, 200, 1200], size=(n, 3))


def test_points_and_properties_read_back_exactly(tmp_path):
    path = tmp_path / "scan.ply"
    p = _points(1000)
    rgb = (np.arange(3000) % 256).astype(np.uint8).reshape(1000, 3)
    label_i = np.arange(-500, 500, dtype=np.int16)
    gap = np.linspace(0, 2, 1000)  # float64 -> double
    write_ply(path, p, red=rgb[:, 0], green=rgb[:, 1], blue=rgb[:, 2], label_i=label_i, gap_mm=gap)

    ply = PlyData.read(str(path))
    assert ply.text is False and ply.byte_order == "<", "binary little-endian"
    assert [e.name for e in ply.elements] == ["vertex"]
    v = ply["vertex"]
    assert v.count == 1000
    names = [prop.name for prop in v.properties]
    assert names == ["x", "y", "z", "red", "green", "blue", "label_i", "gap_mm"]
    types = {prop.name: prop.val_dtype for prop in v.properties}
    assert types["x"] == "f4" and types["red"] == "u1" and types["label_i"] == "i2" and types["gap_mm"] == "f8"
    xyz = np.column_stack([v["x"], v["y"], v["z"]])
    np.testing.assert_array_equal(xyz, p.astype(np.float32))  # stored as float32, bit-exact
    np.testing.assert_array_equal(np.column_stack([v["red"], v["green"], v["blue"]]), rgb)
    np.testing.assert_array_equal(v["label_i"], label_i)
    np.testing.assert_array_equal(v["gap_mm"], gap)
    # Nothing after the last vertex: the body is exactly count × record size.
    body = path.read_bytes().split(b"end_header\n", 1)[1]
    assert len(body) == 1000 * (3 * 4 + 3 * 1 + 2 + 8)


def test_empty_cloud_is_a_valid_ply(tmp_path):
    path = tmp_path / "empty.ply"
    write_ply(path, np.zeros((0, 3)))
    v = PlyData.read(str(path))["vertex"]
    assert v.count == 0 and [prop.name for prop in v.properties] == ["x", "y", "z"]


def test_header_bytes_are_what_other_tools_expect(tmp_path):
    # MeshLab, CloudCompare and Open3D read the header line by line: ASCII, "\n" endings, the format line second.
    path = tmp_path / "scan.ply"
    write_ply(path, _points(3))
    head = path.read_bytes().split(b"end_header\n", 1)[0].decode("ascii").split("\n")
    assert head[0] == "ply" and head[1] == "format binary_little_endian 1.0"
    assert "element vertex 3" in head
    assert [h for h in head if h.startswith("property")] == ["property float x", "property float y", "property float z"]


def test_bad_properties_are_refused(tmp_path):
    with pytest.raises(ValueError, match="has 2 values for 3 points"):
        write_ply(tmp_path / "a.ply", _points(3), red=np.zeros(2, np.uint8))
    with pytest.raises(ValueError, match="identifier"):
        write_ply(tmp_path / "b.ply", _points(3), x=np.zeros(3))
    assert not list(tmp_path.iterdir()), "a refused write leaves no file (atomic)"
