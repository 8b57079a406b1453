"""Point clouds: PLY (ascii, binary little/big endian, any numeric type, extra properties and elements) and .npy."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from drivers.pointcloud import read_point_cloud, write_ply


@pytest.fixture
def points():
    rng = np.random.default_rng(0)
    return (rng.normal(size=(257, 3)) * [3.0, 2.0, 1.0]).astype(np.float32)


@pytest.mark.parametrize("binary", [True, False])
def test_write_read_round_trip(tmp_path, points, binary):
    path = tmp_path / "cloud.ply"
    write_ply(path, points, binary=binary)
    out = read_point_cloud(path)
    assert out.dtype == np.float32 and out.shape == (257, 3)
    np.testing.assert_array_equal(out, points)  # float32 values round-trip exactly in both encodings


@pytest.mark.parametrize("endian,fmt", [("<", "binary_little_endian"), (">", "binary_big_endian")])
def test_binary_with_other_types_properties_and_elements(tmp_path, points, endian, fmt):
    """double x, int16 y, float z, extra uchar colours, a face list element after and a fixed element before."""
    n = len(points)
    vertex = np.zeros(n, dtype=[("nx", endian + "f4"), ("x", endian + "f8"), ("red", "u1"), ("y", endian + "i2"),
                                ("z", endian + "f4"), ("alpha", "u1")])
    ints = np.round(points[:, 1] * 100).astype(np.int16)
    vertex["x"], vertex["y"], vertex["z"] = points[:, 0], ints, points[:, 2]
    before = np.arange(3, dtype=endian + "i4").tobytes()  # element "camera" with 3 int rows
    faces = b"".join(bytes([3]) + np.array([0, 1, 2], dtype=endian + "i4").tobytes() for _ in range(2))
    header = (
        f"ply\nformat {fmt} 1.0\ncomment made by a test\nobj_info nothing\nelement camera 3\nproperty int k\n"
        f"element vertex {n}\nproperty float nx\nproperty double x\nproperty uchar red\nproperty short y\n"
        "property float z\nproperty uchar alpha\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path = tmp_path / "typed.ply"
    path.write_bytes(header.encode() + before + vertex.tobytes() + faces)
    out = read_point_cloud(path)
    np.testing.assert_array_equal(out[:, 0], points[:, 0])
    np.testing.assert_array_equal(out[:, 1], ints.astype(np.float32))
    np.testing.assert_array_equal(out[:, 2], points[:, 2])


def test_binary_list_element_before_vertices(tmp_path):
    header = ("ply\nformat binary_little_endian 1.0\nelement tag 2\nproperty list uchar ushort ids\n"
              "element vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    tags = bytes([2]) + np.array([7, 8], "<u2").tobytes() + bytes([0])
    verts = np.array([[1, 2, 3], [4, 5, 6]], "<f4").tobytes()
    (tmp_path / "t.ply").write_bytes(header.encode() + tags + verts)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "t.ply"), [[1, 2, 3], [4, 5, 6]])


def test_ascii_with_extra_columns_and_elements(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement info 1\nproperty int a\nelement vertex 3\nproperty int id\n"
            "property float z\nproperty float y\nproperty float x\nelement face 1\nproperty list uchar int v\n"
            "end_header\n42\n0 3 2 1\n1 6.5 5 4\n2 -9 8 7e-1\n3 0 1 2\n")
    (tmp_path / "a.ply").write_text(text)
    np.testing.assert_allclose(read_point_cloud(tmp_path / "a.ply"), [[1, 2, 3], [4, 5, 6.5], [0.7, 8, -9]])


def test_npy(tmp_path, points):
    np.save(tmp_path / "p.npy", points.astype(np.float64))
    out = read_point_cloud(tmp_path / "p.npy")
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, points)
    np.save(tmp_path / "bad.npy", points[:, :2])
    with pytest.raises(ValueError, match=r"bad.npy: expected an \(N, 3\) array of points, got shape \(257, 2\)"):
        read_point_cloud(tmp_path / "bad.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match=r"obj.npy: not a plain numeric .npy array"):
        read_point_cloud(tmp_path / "obj.npy")
    np.save(tmp_path / "nan.npy", np.array([[0, 0, 0], [1, np.inf, 2]]))
    with pytest.raises(ValueError, match=r"nan.npy: 1 points with non-finite coordinates \(first: point 1"):
        read_point_cloud(tmp_path / "nan.npy")
    # Finite in the file but not as float32: refused by name, not turned into inf with a RuntimeWarning.
    np.save(tmp_path / "big.npy", np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [1e39, 0.0, 0.0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"big.npy: 1 points with coordinates beyond float32's range \(\+-3.4e38\) "
                                             r"\(first: point 2 = \[1e\+39, 0.0, 0.0\]\)"):
            read_point_cloud(tmp_path / "big.npy")
        ply = tmp_path / "big.ply"
        ply.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                       "property float z\nend_header\n0 0 0\n1 -4e38 2\n")
        with pytest.raises(ValueError, match=r"big.ply: 1 points with coordinates beyond float32's range"):
            read_point_cloud(ply)


def test_errors(tmp_path, points):
    with pytest.raises(FileNotFoundError, match=r"missing.ply: point cloud not found"):
        read_point_cloud(tmp_path / "missing.ply")
    with pytest.raises(ValueError, match=r"cloud.xyz: expected a .ply or .npy point cloud, got suffix '.xyz'"):
        read_point_cloud(tmp_path / "cloud.xyz")
    with pytest.raises(ValueError, match=r"points: expected shape \(N, 3\), got \(4,\)"):
        write_ply(tmp_path / "x.ply", np.zeros(4))

    path = tmp_path / "c.ply"
    write_ply(path, points)
    data = path.read_bytes()
    path.write_bytes(data[:-5])  # the header now lies about the length
    with pytest.raises(ValueError, match=r"c.ply: PLY header declares 257 vertices \(3084 bytes\) but only 3079 bytes"):
        read_point_cloud(path)
    path.write_bytes(b"PLY\n" + data[4:])
    with pytest.raises(ValueError, match=r"c.ply: not a PLY file"):
        read_point_cloud(path)
    path.write_bytes(data.replace(b"end_header", b"end_headxx"))
    with pytest.raises(ValueError, match=r"c.ply: PLY header has no 'end_header' line"):
        read_point_cloud(path)
    path.write_bytes(data.replace(b"property float y", b"property float w"))
    with pytest.raises(ValueError, match=r"c.ply: PLY vertex element has no 'y' property \(has \['x', 'w', 'z'\]\)"):
        read_point_cloud(path)
    path.write_bytes(data.replace(b"property float y", b"property quad y"))
    with pytest.raises(ValueError, match=r"c.ply: header line 6: expected 'property TYPE NAME'"):
        read_point_cloud(path)
    path.write_bytes(data.replace(b"binary_little_endian", b"binary_middle_endian"))
    with pytest.raises(ValueError, match=r"c.ply: header line 2: expected 'format ascii\|binary_little_endian"):
        read_point_cloud(path)
    bad = points.copy()
    bad[7, 2] = np.nan
    write_ply(path, bad)
    with pytest.raises(ValueError, match=r"c.ply: 1 points with non-finite coordinates \(first: point 7"):
        read_point_cloud(path)

    write_ply(path, points[:3], binary=False)
    text = path.read_text().splitlines()
    path.write_text("\n".join(text[:-1]) + "\n")
    with pytest.raises(ValueError, match=r"c.ply: PLY header declares 3 vertices but only 2 vertex lines follow"):
        read_point_cloud(path)
    text[-2] = "1.0 2.0"
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(ValueError, match=r"c.ply: line 10 \(vertex 1\): expected 3 values \(x y z\), got 2"):
        read_point_cloud(path)
    text[-2] = "1.0 2.0 abc"
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(ValueError, match=r"c.ply: line 10 \(vertex 1\): expected numbers, got '1.0 2.0 abc'"):
        read_point_cloud(path)
