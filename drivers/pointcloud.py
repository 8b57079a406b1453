"""Point clouds from disk: PLY (ASCII, binary little- and big-endian) and ``.npy`` (N x 3).

Only the vertex coordinates are read (``x``, ``y``, ``z`` of any PLY numeric type); other vertex properties and
other elements (faces, ...) are skipped. A header that promises more data than the file holds, an unknown type or
a non-finite coordinate raises ``ValueError`` naming the file and what was expected.
"""

from __future__ import annotations

import os
import tokenize
import zipfile
from pathlib import Path

import numpy as np

from reloc.atomic import atomic_write

__all__ = ["read_point_cloud", "read_ply", "write_ply"]

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
_MAX_HEADER_BYTES = 1 << 20


def read_point_cloud(path: str | os.PathLike) -> np.ndarray:
    """Points (N, 3) float32 from a ``.ply`` or ``.npy`` file (chosen by suffix)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".ply":
        return read_ply(p)
    if suffix == ".npy":
        return _read_npy(p)
    raise ValueError(f"{p}: expected a .ply or .npy point cloud, got suffix {p.suffix!r}")


def _read_npy(p: Path) -> np.ndarray:
    try:
        arr = np.load(p, allow_pickle=False)
    except FileNotFoundError:
        raise FileNotFoundError(f"{p}: point cloud not found") from None
    except (ValueError, EOFError, SyntaxError, tokenize.TokenError, zipfile.BadZipFile) as exc:  # bad header/body
        raise ValueError(f"{p}: not a plain numeric .npy array ({type(exc).__name__}: {exc})") from None
    except MemoryError:  # the header claims a shape that would not fit in memory
        raise ValueError(f"{p}: not a plain numeric .npy array (its header claims more data than fits in memory)") from None
    if not isinstance(arr, np.ndarray) or arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{p}: expected an (N, 3) array of points, got shape {getattr(arr, 'shape', None)}")
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{p}: expected a numeric array, got dtype {arr.dtype}")
    return _as_points(arr, p)


def read_ply(path: str | os.PathLike) -> np.ndarray:
    """Vertex positions (N, 3) float32 of a PLY file."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{p}: point cloud not found") from None
    fmt, elements, body_start = _parse_header(data, p)
    if fmt == "ascii":
        first_line = data.count(b"\n", 0, body_start) + 1
        return _read_ascii_vertices(data[body_start:], elements, first_line, p)
    return _read_binary_vertices(data, body_start, elements, _FORMATS[fmt], p)


def write_ply(path: str | os.PathLike, points: np.ndarray, *, binary: bool = True) -> None:
    """Write points (N, 3) as a PLY of float32 ``x y z`` (binary little-endian, or ASCII). Atomic."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {pts.shape}")
    pts = np.ascontiguousarray(pts, dtype=np.float32)
    fmt = "binary_little_endian" if binary else "ascii"
    header = (
        f"ply\nformat {fmt} 1.0\ncomment written by voxelplane-reloc\nelement vertex {len(pts)}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    ).encode("ascii")
    with atomic_write(Path(path), "wb") as fh:
        fh.write(header)
        if binary:
            fh.write(pts.astype("<f4").tobytes())
        else:
            # repr-precision floats round-trip exactly through float32.
            fh.write("".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in pts.tolist()).encode("ascii"))


# --------------------------------------------------------------------------------------------------- PLY


def _parse_header(data: bytes, p: Path) -> tuple[str, list[dict], int]:
    """Format, elements [{name, count, props: [(name, type) | (name, ('list', count_type, item_type))]}], body offset."""
    if not data.startswith(b"ply"):
        raise ValueError(f"{p}: not a PLY file (expected 'ply' on the first line)")
    end = data.find(b"end_header", 0, _MAX_HEADER_BYTES)
    if end < 0:
        raise ValueError(f"{p}: PLY header has no 'end_header' line")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    try:
        lines = data[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise ValueError(f"{p}: PLY header is not ASCII text") from None
    fmt = None
    elements: list[dict] = []
    for lineno, raw in enumerate(lines[1:], start=2):
        tok = raw.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        where = f"{p}: header line {lineno}"
        if tok[0] == "format":
            if len(tok) != 3 or tok[1] not in _FORMATS:
                raise ValueError(f"{where}: expected 'format ascii|binary_little_endian|binary_big_endian 1.0', got {raw!r}")
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                raise ValueError(f"{where}: expected 'element NAME COUNT', got {raw!r}")
            elements.append({"name": tok[1], "count": int(tok[2]), "props": []})
        elif tok[0] == "property":
            if not elements:
                raise ValueError(f"{where}: property before any element")
            if len(tok) >= 3 and tok[-1] in [name for name, _ in elements[-1]["props"]]:
                raise ValueError(f"{where}: property {tok[-1]!r} declared twice in element {elements[-1]['name']!r}")
            if len(tok) == 3 and tok[1] in _PLY_TYPES:
                elements[-1]["props"].append((tok[2], _PLY_TYPES[tok[1]]))
            elif len(tok) == 5 and tok[1] == "list" and tok[2] in _PLY_TYPES and tok[3] in _PLY_TYPES:
                elements[-1]["props"].append((tok[4], ("list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]])))
            else:
                raise ValueError(f"{where}: expected 'property TYPE NAME' or 'property list TYPE TYPE NAME' with "
                                 f"types {sorted(set(_PLY_TYPES))}, got {raw!r}")
        else:
            raise ValueError(f"{where}: unexpected header keyword {tok[0]!r}")
    if fmt is None:
        raise ValueError(f"{p}: PLY header has no 'format' line")
    vertex = [e for e in elements if e["name"] == "vertex"]
    if not vertex:
        raise ValueError(f"{p}: PLY header declares no 'vertex' element")
    names = [name for name, _ in vertex[0]["props"]]
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise ValueError(f"{p}: PLY vertex element has no '{axis}' property (has {names})")
        if isinstance(dict(vertex[0]["props"])[axis], tuple):
            raise ValueError(f"{p}: PLY vertex property '{axis}' is a list, expected a scalar")
    return fmt, elements, body_start


def _read_binary_vertices(data: bytes, offset: int, elements: list[dict], endian: str, p: Path) -> np.ndarray:
    for element in elements:
        props = element["props"]
        fixed = all(not isinstance(t, tuple) for _, t in props)
        if element["name"] == "vertex":
            if not fixed:
                raise ValueError(f"{p}: PLY vertex element with list properties is not supported")
            dtype = np.dtype([(name, endian + t) for name, t in props])
            need = dtype.itemsize * element["count"]
            if offset + need > len(data):
                raise ValueError(
                    f"{p}: PLY header declares {element['count']} vertices ({need} bytes) but only "
                    f"{len(data) - offset} bytes follow the previous data"
                )
            v = np.frombuffer(data, dtype=dtype, count=element["count"], offset=offset)
            return _as_points(np.stack([v["x"], v["y"], v["z"]], axis=1), p)
        offset = _skip_binary_element(data, offset, element, endian, p)
    raise AssertionError("unreachable: the header check guarantees a vertex element")


def _skip_binary_element(data: bytes, offset: int, element: dict, endian: str, p: Path) -> int:
    props = element["props"]
    if all(not isinstance(t, tuple) for _, t in props):
        size = np.dtype([(n, endian + t) for n, t in props]).itemsize * element["count"]
        if offset + size > len(data):
            raise ValueError(f"{p}: PLY element '{element['name']}' declares {element['count']} rows but the file ends")
        return offset + size
    for _ in range(element["count"]):
        for _, t in props:
            if isinstance(t, tuple):
                _, count_t, item_t = t
                ct = np.dtype(endian + count_t)
                if offset + ct.itemsize > len(data):
                    raise ValueError(f"{p}: PLY element '{element['name']}' runs past the end of the file")
                n = int(np.frombuffer(data, dtype=ct, count=1, offset=offset)[0])
                if n < 0:  # (a negative length would step back: rows could loop over the same bytes forever)
                    raise ValueError(f"{p}: PLY element '{element['name']}' has a list of negative length {n}")
                offset += ct.itemsize + n * np.dtype(item_t).itemsize
            else:
                offset += np.dtype(t).itemsize
    return offset


def _read_ascii_vertices(body: bytes, elements: list[dict], first_line: int, p: Path) -> np.ndarray:
    """``first_line``: the file line number of the first body line (for messages)."""
    lines = body.decode("ascii", errors="replace").splitlines()
    start = 0
    for element in elements:
        if element["name"] == "vertex":
            rows = lines[start:start + element["count"]]
            if len(rows) < element["count"]:
                raise ValueError(
                    f"{p}: PLY header declares {element['count']} vertices but only {len(rows)} vertex lines follow"
                )
            names = [name for name, _ in element["props"]]
            cols = [names.index(a) for a in ("x", "y", "z")]
            pts = np.empty((len(rows), 3), dtype=np.float64)
            for i, line in enumerate(rows):
                tok = line.split()
                where = f"{p}: line {first_line + start + i} (vertex {i})"
                if len(tok) != len(names):
                    raise ValueError(f"{where}: expected {len(names)} values ({' '.join(names)}), got {len(tok)}")
                try:
                    pts[i] = [float(tok[c]) for c in cols]
                except ValueError:
                    raise ValueError(f"{where}: expected numbers, got {line!r}") from None
            return _as_points(pts, p)
        start += element["count"]
    raise AssertionError("unreachable: the header check guarantees a vertex element")


def _as_points(arr: np.ndarray, p: Path) -> np.ndarray:
    """``arr`` (N, 3) as float32 points, refusing coordinates that are not finite or beyond float32's range (a
    float64 or integer file may hold them; cast, they would become inf with a RuntimeWarning)."""
    if arr.dtype != np.float32:
        a64 = arr.astype(np.float64, copy=False)  # no copy of a float64 file's array
        with np.errstate(invalid="ignore"):
            big = (np.isfinite(a64) & (np.abs(a64) > np.finfo(np.float32).max)).any(axis=1)
        if big.any():
            i = int(np.argmax(big))
            raise ValueError(f"{p}: {int(big.sum())} points with coordinates beyond float32's range (+-3.4e38) "
                             f"(first: point {i} = {arr[i].tolist()})")
    return _check_finite(np.ascontiguousarray(arr, dtype=np.float32), p)


def _check_finite(pts: np.ndarray, p: Path) -> np.ndarray:
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{p}: {int(bad.sum())} points with non-finite coordinates (first: point {i} = {pts[i].tolist()})")
    return pts
