"""Fuzzing map files: a valid map's bytes truncated and bit-flipped, its archive rewritten with arrays of the wrong
dtype or shape, missing, extra or non-finite arrays, metadata that lies (version, format, counts), an object array
(a pickle) inside, and random bytes.

Property: ``load_map`` returns a map or raises :class:`MapFileError` naming the file, and never unpickles anything.
A map that loads has finite planes with unit normals, a unit gravity (or none), one observation count per plane, and
a relocalizer can be built on it.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from reloc.evaluation.synthetic import furnished_room, scene_planes
from reloc.mapping import MapFileError, PlaneMap, load_map, save_map
from reloc.matching import Relocalizer
from test_fuzz_common import Target, fuzz_settings, outcome


def _valid_map_bytes() -> bytes:
    planes = scene_planes(furnished_room("office"), spacing=0.25)
    keys = np.arange(0, 4000, 7, dtype=np.int64)
    meta = {"source": "fuzz", "created_utc": "2026-01-01T00:00:00+00:00"}  # fixed: the same bytes on every run
    pm = PlaneMap(planes, np.full(len(planes), 3), meta, free_keys=keys, free_voxel_m=0.15)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.npz"
        save_map(path, pm)
        return path.read_bytes()


VALID = _valid_map_bytes()


def _entries(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


ENTRIES = _entries(VALID)
META = json.loads(bytes(ENTRIES["meta"]).decode())


class _Marker:
    """Unpickling this creates ``path`` (so a test can see whether anything was unpickled)."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return (os.mkdir, (self.path,))


def _archive(arrays: dict, compressed: bool, pickles: bool = False) -> bytes:
    buf = io.BytesIO()
    if pickles:
        # np.savez refuses nothing: an object array is pickled into the .npy entry.
        with zipfile.ZipFile(buf, "w") as zf:
            for name, arr in arrays.items():
                with zf.open(name + ".npy", "w") as fh:
                    np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=True)
    else:
        (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


meta_values = st.one_of(
    st.none(), st.booleans(), st.integers(-3, 5), st.floats(allow_nan=True), st.text(max_size=6),
    st.lists(st.integers(), max_size=2), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)


@st.composite
def map_files(draw) -> tuple[bytes, str | None]:
    """(file bytes, marker directory that must not appear or None)."""
    kind = draw(st.integers(0, 9))
    if kind == 0:  # truncated
        return VALID[: draw(st.integers(0, len(VALID) - 1))], None
    if kind == 1:  # bits flipped
        b = bytearray(VALID)
        for _ in range(draw(st.integers(1, 8))):
            bit = draw(st.integers(0, len(b) * 8 - 1))
            b[bit // 8] ^= 1 << (bit % 8)
        return bytes(b), None
    if kind == 2:  # random bytes, or a zip / npy magic followed by them
        head = draw(st.sampled_from([b"", b"PK\x03\x04", b"\x93NUMPY\x01\x00", VALID[:60]]))
        return head + draw(st.binary(max_size=200)), None
    arrays = dict(ENTRIES)
    names = sorted(arrays)
    marker = None
    if kind == 3:  # an entry missing, or an extra one
        if draw(st.booleans()):
            del arrays[draw(st.sampled_from(names))]
        else:
            arrays[draw(st.text("abcxyz_", min_size=1, max_size=6))] = np.zeros(3)
    elif kind == 4:  # an array of another dtype
        name = draw(st.sampled_from(names))
        dtype = draw(st.sampled_from(["<U3", "S2", "c16", "bool", "i1", "u8", "f2", "M8[s]", "m8[s]", "V8",
                                      "i4,f8", ">f8", "<f4"]))
        try:
            arrays[name] = arrays[name].astype(dtype)
        except (TypeError, ValueError):
            arrays[name] = np.zeros(arrays[name].shape, dtype=dtype)
    elif kind == 5:  # an array of another shape
        name = draw(st.sampled_from(names))
        arr = arrays[name]
        choice = draw(st.integers(0, 4))
        if choice == 0:
            arrays[name] = arr.reshape(-1)
        elif choice == 1:
            arrays[name] = arr[: draw(st.integers(0, max(len(arr) - 1, 0)))] if arr.ndim else arr.reshape(1)
        elif choice == 2:
            arrays[name] = np.concatenate([arr, arr]) if arr.ndim else np.stack([arr, arr])
        elif choice == 3:
            arrays[name] = np.asarray(arr.reshape(-1)[:1].sum() if arr.size else 0)  # 0-d
        else:
            arrays[name] = np.zeros((0,) * draw(st.integers(1, 3)), arr.dtype)
    elif kind == 6:  # values: non-finite, huge, zero, negative
        name = draw(st.sampled_from([n for n in names if n != "meta"]))
        arr = arrays[name].copy()
        if arr.size:
            flat = arr.reshape(-1)
            i = draw(st.integers(0, flat.size - 1))
            v = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, -1.0, 2.0**62, -(2.0**62)]))
            if arr.dtype.kind in "iu":
                v = 0 if not np.isfinite(v) else int(max(min(v, 2**62), -(2**62)))
            flat[i] = v
        arrays[name] = arr
    elif kind == 7:  # metadata edited
        meta = dict(META)
        key = draw(st.sampled_from(sorted(meta) + ["extra"]))
        if draw(st.booleans()):
            meta.pop(key, None)
        else:
            meta[key] = draw(meta_values)
        arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    elif kind == 8:  # metadata that is not a JSON object
        raw = draw(st.one_of(st.binary(max_size=40), st.sampled_from([b"[]", b"1", b'"x"', b"null", b"{"])))
        arrays["meta"] = np.frombuffer(raw, np.uint8)
    else:  # an object array (a pickle) inside
        tmp = tempfile.mkdtemp()
        marker = os.path.join(tmp, "unpickled")
        name = draw(st.sampled_from(names))
        arrays[name] = np.array([_Marker(marker), 1], dtype=object)
        return _archive(arrays, False, pickles=True), marker
    return _archive(arrays, draw(st.booleans())), marker


def check_map(data: bytes, marker: str | None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzzed.npz"
        path.write_bytes(data)
        try:
            pm = load_map(path)
        finally:
            if marker is not None:
                assert not os.path.exists(marker), "a pickle inside the map file was unpickled"
    p = pm.planes
    assert np.isfinite(p.normals).all() and np.isfinite(p.offsets).all() and np.isfinite(p.sample_points).all()
    assert np.allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-6)
    assert p.gravity is None or (np.isfinite(p.gravity).all() and abs(np.linalg.norm(p.gravity) - 1) < 1e-9)
    assert pm.observations.shape == (len(p),)
    assert np.isfinite(pm.free_voxel_m) and (len(pm.free_keys) == 0 or pm.free_voxel_m > 0)
    Relocalizer(pm)


def run(case) -> str:
    return outcome(lambda: check_map(*case), names="fuzzed.npz", clear=(MapFileError,))


TARGET = Target("map_file", "map file (.npz)", map_files(), run)


def test_valid_map_loads():
    assert run((VALID, None)) == "ok"


@fuzz_settings(150)
@given(map_files())
def test_fuzzed_map_files_load_or_raise_map_file_error(case):
    run(case)


def test_pickle_inside_is_refused_without_unpickling(tmp_path):
    marker = str(tmp_path / "unpickled")
    for name in ("meta", "plane_normals", "observations"):
        arrays = dict(ENTRIES)
        arrays[name] = np.array([_Marker(marker), 1], dtype=object)
        assert run((_archive(arrays, False, pickles=True), marker)) == "error"


# Regressions found by the fuzzer (each escaped, as TypeError or a map with a NaN gravity, before its fix).


def _with(**changes) -> bytes:
    arrays = dict(ENTRIES)
    meta = dict(META)
    for name, value in changes.items():
        if name.startswith("meta_"):
            meta[name[len("meta_"):]] = value
        else:
            arrays[name] = value
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    return _archive(arrays, True)


def test_records_text_and_complex_arrays_are_refused():
    n = len(ENTRIES["observations"])
    for name, arr in [
        ("observations", np.zeros(n, dtype="i4,f8")),  # TypeError from the int64 cast before
        ("plane_normals", ENTRIES["plane_normals"].astype("<U24")),  # parsed as numbers before
        ("plane_offsets", ENTRIES["plane_offsets"].astype("c16")),  # imaginary part dropped before
    ]:
        assert run((_with(**{name: arr}), None)) == "error"


def test_metadata_free_voxel_size_of_the_wrong_type_is_refused():
    for value in (None, {"a": 1}, [0.1], "0.15", float("nan"), -1.0, True):
        assert run((_with(meta_free_voxel_m=value), None)) == "error"


def test_zero_or_overflowing_gravity_is_refused():
    for g in ([0.0, 0.0, 0.0], [1e300, 1e300, 0.0]):  # a NaN gravity in the loaded map before
        assert run((_with(plane_gravity=np.array(g)), None)) == "error"
    assert run((_with(plane_gravity=np.full(3, np.nan)), None)) == "ok"  # NaN: a map without gravity


def test_non_finite_or_negative_plane_sizes_are_refused():
    # A NaN area loaded before; the relocalizer then refused the map with a ValueError that named no file.
    for name, value in [("plane_areas", np.nan), ("plane_radii", np.inf), ("plane_areas", -1.0),
                        ("plane_centroids", np.nan), ("plane_counts", -5)]:
        arr = ENTRIES[name].copy()
        arr.reshape(-1)[0] = value
        assert run((_with(**{name: arr}), None)) == "error", name


def test_unknown_compression_method_is_a_map_file_error():
    # A flipped bit in an entry's compression method: zipfile's NotImplementedError escaped before.
    data = bytearray(_archive(dict(ENTRIES), compressed=False))
    central = data.index(b"PK\x01\x02")
    data[central + 10] = 99  # the first entry's method in the central directory: not one zipfile knows
    assert run((bytes(data), None)) == "error"
