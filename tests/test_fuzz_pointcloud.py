"""Fuzzing point cloud files: PLY headers (ASCII, binary little- and big-endian) with any elements, properties and
counts, whose bodies hold fewer, more or other bytes than the header says, list properties with any lengths (negative
ones included), non-finite and overflowing coordinates; ``.npy`` arrays of any shape and dtype, pickles, truncations.

Property: ``read_point_cloud`` returns (N, 3) finite float32 points (exactly the written ones for a well-formed
file) or raises ``ValueError`` naming the file.
"""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from drivers.pointcloud import read_point_cloud, write_ply
from test_fuzz_common import Target, fuzz_settings, outcome

TYPES = ["char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint8", "float32", "float64"]
finite = st.floats(-10, 10, width=32)
special = st.sampled_from([np.nan, np.inf, -np.inf, 1e39, -1e300, 0.0])
coords = st.integers(0, 29).flatmap(lambda k: special if k == 0 else finite)  # 1 in 30 special


@st.composite
def ply_files(draw) -> tuple[bytes, np.ndarray | None]:
    """(file bytes, the points when the file is well-formed and finite, else None)."""
    n = draw(st.integers(0, 6))
    pts = np.array(draw(st.lists(st.tuples(coords, coords, coords), min_size=n, max_size=n)), np.float64).reshape(n, 3)
    fmt = draw(st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian"]))
    honest = draw(st.booleans())
    lines = ["ply", f"format {fmt} 1.0"]
    props = [("float", "x"), ("float", "y"), ("float", "z")]
    elements = []
    if not honest:
        # Other elements before the vertices, other properties, lying counts, missing axes, bad keywords.
        if draw(st.booleans()):
            elements.append(("face", draw(st.sampled_from([0, 1, 2, 10**6, 10**12])),
                             [(draw(st.sampled_from(["list uchar int", "list char uchar"])), "vertex_indices")]
                             if draw(st.booleans()) else [("char", "f")]))
        props = [(draw(st.sampled_from(TYPES)), name) for name in draw(
            st.lists(st.sampled_from(["x", "y", "z", "nx", "red", "x"]), min_size=0, max_size=5))]
        if draw(st.booleans()):
            props.append(("list char float", "bad"))
    count = n if honest or draw(st.booleans()) else draw(st.sampled_from([0, n + 1, 2**31, 10**15, max(n - 1, 0)]))
    for name, c, ps in elements:
        lines.append(f"element {name} {c}")
        lines += [f"property {t} {p}" for t, p in ps]
    lines.append(f"element vertex {count}")
    lines += [f"property {t} {p}" for t, p in props]
    if not honest and draw(st.integers(0, 5)) == 0:
        lines.insert(draw(st.integers(1, len(lines))), draw(st.sampled_from(
            ["format ascii", "element", "property float", "bogus 1", "element vertex -3", "property list x y"])))
    header = ("\n".join(lines) + "\nend_header\n").encode()
    names = [p for _, p in props]
    # Body: the vertex rows as the header describes them (when it can), for the other elements random bytes.
    body = b""
    for _, c, _ in elements:
        body += draw(st.one_of(st.binary(max_size=20), st.sampled_from([b"\x01\x00\xfd\x00", b"\x00" * 8])))
    rows = pts if names == ["x", "y", "z"] else np.zeros((n, len(names)))
    if fmt == "ascii":
        body += "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in rows).encode()
    else:
        try:
            end = "<" if fmt == "binary_little_endian" else ">"
            dt = np.dtype([(f"p{i}", end + np.dtype({"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2",
                                                         "int": "i4", "uint": "u4", "float": "f4", "double": "f8",
                                                         "int8": "i1", "uint8": "u1", "float32": "f4",
                                                         "float64": "f8"}.get(t, "f4")).str[1:])
                           for i, (t, _) in enumerate(props)])
            rec = np.zeros(n, dt)
            for i in range(len(props)):
                with np.errstate(all="ignore"):
                    rec[f"p{i}"] = rows[:, i] if rows.shape[1] > i else 0
            body += rec.tobytes()
        except (ValueError, TypeError, OverflowError):
            body += draw(st.binary(max_size=40))
    tail = draw(st.sampled_from([b"", b"", b"\n", b"garbage"]))
    data = header + body + tail
    cut = draw(st.integers(0, 3))
    if cut == 0 and not honest:
        data = data[: draw(st.integers(0, len(data)))]
    with np.errstate(over="ignore"):  # a coordinate beyond float32's range must make the reader refuse the file
        fits = bool(np.isfinite(pts.astype(np.float32)).all())
    expected = pts.astype(np.float32) if honest and fits and not tail.strip() else None
    return data, expected


@st.composite
def npy_files(draw) -> tuple[bytes, None]:
    kind = draw(st.integers(0, 3))
    shape = draw(st.sampled_from([(0, 3), (4, 3), (3,), (2, 2), (2, 3, 1), (), (5, 4)]))
    dtype = draw(st.sampled_from(["f4", "f8", "i2", "u1", "bool", "c8", "U2", "f2", "i4,f4", "M8[s]"]))
    buf = io.BytesIO()
    if kind == 3:
        np.save(buf, np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
    else:
        arr = np.zeros(shape, dtype=dtype)
        if arr.dtype.kind == "f" and arr.size and draw(st.booleans()):
            with np.errstate(over="ignore"):  # 1e30 in float16 is inf: one more extreme value, as meant
                arr.reshape(-1)[0] = draw(st.sampled_from([np.nan, np.inf, 1e30]))
        np.save(buf, arr)
    data = buf.getvalue()
    if kind == 1:
        data = data[: draw(st.integers(0, len(data)))]
    elif kind == 2 and data:
        b = bytearray(data)
        b[draw(st.integers(0, len(b) - 1))] ^= 1 << draw(st.integers(0, 7))
        data = bytes(b)
    return data, None


clouds = st.one_of(
    st.tuples(st.just(".ply"), ply_files()),
    st.tuples(st.just(".npy"), npy_files()),
    st.tuples(st.sampled_from([".ply", ".npy"]), st.tuples(st.binary(max_size=200), st.none())),
)


def check_cloud(suffix: str, data: bytes, expected) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"fuzzed{suffix}"
        path.write_bytes(data)
        pts = read_point_cloud(path)
    assert pts.ndim == 2 and pts.shape[1] == 3 and pts.dtype == np.float32 and np.isfinite(pts).all()
    if expected is not None:
        np.testing.assert_array_equal(pts, expected)


def run(case) -> str:
    suffix, (data, expected) = case
    return outcome(lambda: check_cloud(suffix, data, expected), names=f"fuzzed{suffix}")


TARGET = Target("point_cloud", "point cloud (PLY, .npy)", clouds, run)


@fuzz_settings(200)
@given(clouds)
def test_fuzzed_point_clouds_read_exactly_or_raise_value_error(case):
    run(case)


def test_written_clouds_read_back_exactly(tmp_path):
    pts = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
    for binary in (True, False):
        write_ply(tmp_path / "c.ply", pts, binary=binary)
        np.testing.assert_array_equal(read_point_cloud(tmp_path / "c.ply"), pts)


# Regressions found by the fuzzer (each escaped before its fix).


def test_negative_list_length_is_refused_not_looped_over(tmp_path):
    # A face list of length -3 stepped back onto the previous row: 10^12 rows looped over the same bytes (a hang).
    header = (b"ply\nformat binary_little_endian 1.0\nelement face 1000000000000\nproperty list char uchar idx\n"
              b"element vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
    p = tmp_path / "cycle.ply"
    p.write_bytes(header + bytes([1, 0, 0xFD, 0]) + bytes(12))
    assert outcome(lambda: read_point_cloud(p), names="cycle.ply", timeout_s=5) == "error"


def test_duplicate_property_is_refused_with_the_file_named(tmp_path):
    p = tmp_path / "dup.ply"
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                  b"property float z\nproperty float x\nend_header\n")  # numpy's "field 'x' occurs more than once"
    assert outcome(lambda: read_point_cloud(p), names="dup.ply") == "error"


def test_npy_with_a_bad_header_is_a_value_error(tmp_path):
    p = tmp_path / "bad.npy"
    for data in (b"", b"PK\x03\x04", b"\x93NUMPY\x01\x00v\x00{'descr': '<i2', 'fortran_order': False, 'shape': (2, 2), }  (" + b" " * 60
                 + b"\n" + bytes(8)):  # EOFError, BadZipFile (zip magic), TokenError before
        p.write_bytes(data)
        assert outcome(lambda: read_point_cloud(p), names="bad.npy") == "error"
