"""Plane maps: fusion against the simulator's ground truth, submaps, and the map file (round trip and errors)."""

from __future__ import annotations

import io
import json
import math
import zipfile

import numpy as np
import pytest

import sim
from helpers import corridor_walk
from reloc.evaluation.synthetic import furnished_room, look_at, view_planes
from reloc.mapping import (
    MapBuilder,
    MapFileError,
    MappingParams,
    PlaneMap,
    SubmapBuilder,
    build_map,
    build_submap,
    grow_submap,
    load_map,
    odometry_consistent_frames,
    oracle_source,
    plane_fit_from_stats,
    save_map,
    select_keyframes,
    submap_constrained,
)
from reloc.matching import MatchingParams
from reloc.matching.index import build_index
from reloc.mapping.plane_map import MAP_FORMAT_VERSION
from reloc.planes import plane_errors
from reloc.transforms import exp_se3
from sim.scenes import make_scene


@pytest.fixture(scope="module")
def living_map():
    scene = make_scene("living_room")
    frames = sim.simulate_frames(scene, "handheld", 240, noise="none", camera="kinect", seed=3, width=96, height=72)
    return scene, build_map(frames, oracle_source(scene), MappingParams(), meta={"source": "test"})


def test_plane_fit_from_stats_recovers_a_plane():
    rng = np.random.default_rng(0)
    n = np.array([0.3, -0.4, 0.866])
    n /= np.linalg.norm(n)
    u = np.cross(n, [1, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    pts = 2.0 * n + rng.uniform(-1, 1, (500, 1)) * u + rng.uniform(-1, 1, (500, 1)) * v
    pts += rng.normal(0, 0.002, (500, 1)) * n
    normals, offsets, cents, covs = plane_fit_from_stats(pts.sum(0)[None], (pts.T @ pts)[None], np.array([500]),
                                                         n[None])
    ang, off = plane_errors(np.r_[normals[0], offsets[0]], np.r_[n, -2.0])
    assert ang < 0.1 and off < 0.001
    # The covariance is symmetric, positive semi-definite, and small for 500 points at 2 mm noise.
    assert np.allclose(covs[0], covs[0].T) and np.linalg.eigvalsh(covs[0]).min() > -1e-12
    assert np.sqrt(covs[0][3, 3]) < 1e-3


def test_keyframes_by_motion():
    T = np.tile(np.eye(4), (10, 1, 1))
    T[:, 0, 3] = np.arange(10) * 0.08  # 8 cm per frame
    assert select_keyframes(T, 0.2, math.radians(10)).tolist() == [0, 3, 6, 9]


def test_map_planes_match_the_scene(living_map):
    scene, pm = living_map
    assert pm.planes.frame == "map" and np.allclose(pm.gravity, [0, 0, -1])
    assert pm.meta["keyframe_count"] >= 10 and pm.meta["frame_count"] == 240
    # Every map plane lies on a scene plane (exact oracle input), and no two map planes are one surface that
    # touches itself: each scene plane id appears as one map plane per connected piece, so at most a few.
    errors = []
    for n, d in zip(pm.planes.normals, pm.planes.offsets):
        cand = [plane_errors(np.r_[n, d], np.r_[sn, sd]) for sn, sd in zip(scene.normals, scene.offsets)]
        errors.append(min(cand, key=lambda e: e[0] + 100 * e[1]))
    errors = np.array(errors)
    assert errors[:, 0].max() < 0.05 and errors[:, 1].max() < 0.002
    assert len(pm) >= 15


def test_fusion_makes_one_plane_per_surface():
    # The same wall seen from three poses, each seeing a different, overlapping part of it.
    rects = furnished_room("living")
    builder = MapBuilder(MappingParams())
    for x in (1.5, 3.0, 4.5):
        T = look_at((x, 3.0, 1.3), (x, 0.0, 1.0))
        builder.add(view_planes(rects, T, hfov_deg=40), T)
    pm = builder.finish()
    wall = np.flatnonzero((pm.planes.normals @ [0, 1, 0] > 0.99) & (np.abs(pm.planes.offsets) < 0.01))
    assert len(wall) == 1
    i = wall[0]
    assert pm.observations[i] == 3
    xs = pm.planes.samples_of(i)[:, 0]
    assert xs.min() < 0.9 and xs.max() > 5.1  # the union of the three views


def test_submap_window_is_in_the_latest_camera_frame():
    rects = furnished_room("office")
    Ts = [look_at((1.0 + 0.3 * k, 2.5, 1.3), (4.0, 4.0 - 0.5 * k, 0.7)) for k in range(4)]
    sets = [view_planes(rects, T) for T in Ts]
    sub = build_submap(sets, Ts)
    single = build_submap(sets[-1:])
    assert sub.frame == "cam" and len(sub) >= len(single)
    np.testing.assert_allclose(sub.gravity, sets[-1].gravity)
    # Each fused plane, moved to the world with the latest pose, is a scene plane.
    world = sub.transformed(Ts[-1], "map")
    for n, d in zip(world.normals, world.offsets):
        best = min(plane_errors(np.r_[n, d], np.r_[np.array(r.normal), -np.dot(r.normal, r.center)]) for r in rects
                   if np.dot(r.normal, n) > 0.9)
        assert best[0] < 0.05 and best[1] < 0.002
    # The window's cameras, in the latest camera's frame (the origin alone for one frame).
    np.testing.assert_allclose(world.viewpoints, [T[:3, 3] for T in Ts], atol=1e-12)
    np.testing.assert_array_equal(single.viewpoints, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="T_odom_cams"):
        build_submap(sets, Ts[:2])


def test_a_submap_builder_restarts_after_a_frame_without_odometry():
    """A frame without odometry cannot be placed against the frames before it, nor the frame after it against it:
    the window restarts on both (the first was kept at the identity, and the next frame's odometry pose was taken
    relative to it, as if the first camera had stood at the origin of odometry). A window of 0 frames is refused,
    not taken for the default."""
    rects = furnished_room("living")
    Ts = [look_at((1.0 + 0.1 * k, 1.0 + 0.05 * k, 1.4), (4.0, 3.5 - 0.05 * k, 1.0)) for k in range(3)]
    sets = [view_planes(rects, T) for T in Ts]
    sb = SubmapBuilder(MappingParams(), window_frames=3)
    sb.push(sets[0], None)
    assert len(sb) == 1 and np.array_equal(sb.submap().normals, build_submap(sets[:1]).normals)
    sb.push(sets[1], Ts[1])
    assert len(sb) == 1
    alone = build_submap(sets[1:2])
    sub = sb.submap()
    assert np.array_equal(sub.normals, alone.normals) and np.array_equal(sub.offsets, alone.offsets)
    np.testing.assert_array_equal(sub.viewpoints, np.zeros((1, 3)))
    sb.push(sets[2], Ts[2])  # odometry on both: the window grows again
    assert len(sb) == 2
    np.testing.assert_allclose(sb.submap().viewpoints, build_submap(sets[1:], Ts[1:]).viewpoints, atol=1e-12)
    with pytest.raises(ValueError, match="window_frames: expected an integer >= 1, got 0"):
        SubmapBuilder(MappingParams(), window_frames=0)


def test_odometry_check_leaves_out_a_frame_whose_odometry_is_off():
    rects = furnished_room("office")
    Ts = [look_at((1.0 + 0.3 * k, 2.5, 1.3), (4.0, 4.0 - 0.5 * k, 0.7)) for k in range(4)]
    sets = [view_planes(rects, T) for T in Ts]
    params = MappingParams()
    assert odometry_consistent_frames(sets, Ts, params).tolist() == [True] * 4  # exact odometry: all kept

    def off(k, xi):
        out = list(Ts)
        out[k] = exp_se3(np.asarray(xi, float)) @ Ts[k]  # frame k placed wrong by the odometry
        return out

    # Turned 2 degrees about the vertical, or 5 cm sideways: left out, and the submap is the other three's.
    for xi in ([0, 0, 0, 0, 0, math.radians(2.0)], [0.05, 0, 0, 0, 0, 0]):
        bad = off(1, xi)
        assert odometry_consistent_frames(sets, bad, params).tolist() == [True, False, True, True], xi
        stats = {}
        sub = build_submap(sets, bad, params, stats)
        ref = build_submap([sets[i] for i in (0, 2, 3)], [Ts[i] for i in (0, 2, 3)], params)
        assert stats == {"frames_left_out": 1}
        np.testing.assert_allclose(sub.normals, ref.normals, atol=1e-12)
        np.testing.assert_allclose(sub.offsets, ref.offsets, atol=1e-12)
    # Below the floors (0.5 deg, 1 cm at these 2-5 m) the frame is kept; with the check off, any frame is.
    assert odometry_consistent_frames(sets, off(1, [0.005, 0, 0, 0, 0, math.radians(0.2)]), params).all()
    assert odometry_consistent_frames(sets, off(1, [0, 0, 0, 0, 0, math.radians(5)]),
                                      MappingParams(submap_check_sigmas=0.0)).all()
    # When the newest frame's odometry is the one off, every older frame disagrees with it: the newest stands alone.
    stats = {}
    alone = build_submap(sets, off(3, [0, 0, 0, 0, 0, math.radians(2.0)]), params, stats)
    assert stats == {"frames_left_out": 3}
    np.testing.assert_allclose(alone.normals, build_submap(sets[-1:]).normals, atol=1e-12)
    # A fraction of 0: any disagreeing plane leaves its frame out, agreeing ones never do.
    assert odometry_consistent_frames(sets, Ts, MappingParams(submap_check_fraction=0.0)).all()
    with pytest.raises(ValueError, match="submap_check_sigmas"):
        MappingParams(submap_check_sigmas=-1.0)
    with pytest.raises(ValueError, match=r"submap_check_fraction: expected a fraction in \[0, 1\]"):
        MappingParams(submap_check_fraction=1.5)


def test_a_submap_that_cannot_pin_a_pose_grows_back_in_time():
    Ts, sets = corridor_walk(40)
    params = MappingParams()
    newest = build_submap(sets[-10:], Ts[-10:], params)
    assert len(newest) == 4  # floor, ceiling, two walls: nothing fixes where along the corridor
    assert submap_constrained(newest, params) == (False, "4 planes of at least 0.5 m^2 (needs 6)")
    assert submap_constrained(newest, params.with_(submap_grow_min_planes=4)) == (
        False, "0.00 m^2 along its weakest direction (needs 1.0)")
    asked = []

    def fetch(k):
        asked.append(k)
        return sets[-k:], Ts[-k:]

    stats = {}
    sub, used = grow_submap(fetch, 10, 40, params, stats)
    # Half the first window at a time, until the cabinet's faces are in: the one facing back along the corridor
    # (1.2 m^2) pins the translation along it.
    assert asked == [10, 15, 20, 25, 30, 35] and used == 35 and stats == {"frames_left_out": 0, "window_frames": 35}
    assert submap_constrained(sub, params) == (True, "")
    world = sub.transformed(Ts[-1], "map")
    back = np.flatnonzero(world.normals[:, 0] < -0.99)
    assert len(back) == 1 and abs(world.areas[back[0]] - 1.2) < 0.05 and abs(world.offsets[back[0]] - 5.5) < 1e-9
    ref = build_submap(sets[-35:], Ts[-35:], params)
    np.testing.assert_allclose(sub.offsets, ref.offsets, atol=1e-12)
    # At most `most` frames, or as far as the history goes; a constrained window does not grow.
    asked.clear()
    assert grow_submap(fetch, 10, 22, params)[1] == 22 and asked == [10, 15, 20, 22]
    assert grow_submap(lambda k: (sets[-min(k, 12):], Ts[-min(k, 12):]), 10, 40, params)[1] == 12
    asked.clear()
    assert grow_submap(fetch, 40, 80, params)[1] == 40 and asked == [40]
    with pytest.raises(ValueError, match="first, most"):
        grow_submap(fetch, 10, 5, params)
    with pytest.raises(ValueError, match="submap_max_window_frames: expected 0"):
        MappingParams(submap_window_frames=10, submap_max_window_frames=5)


def test_map_round_trip(tmp_path, living_map):
    _, pm = living_map
    path = save_map(tmp_path / "m.npz", pm)
    back = load_map(path)
    assert len(back) == len(pm) and back.meta["format_version"] == MAP_FORMAT_VERSION
    assert back.meta["source"] == "test" and back.meta["plane_count"] == len(pm)
    for name, a in pm.planes.to_arrays().items():
        np.testing.assert_array_equal(back.planes.to_arrays()[name], a)
    np.testing.assert_array_equal(back.observations, pm.observations)


def _rewrite(src, dst, change):
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = change(item.filename, zin.read(item.filename))
            if data is not None:
                zout.writestr(item, data)


def test_corrupted_map_files_raise_the_named_error(tmp_path, living_map):
    _, pm = living_map
    good = save_map(tmp_path / "good.npz", pm)
    raw = good.read_bytes()

    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(raw[: len(raw) // 2])
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"this is not a map" * 10)
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))

    no_meta = tmp_path / "no_meta.npz"
    _rewrite(good, no_meta, lambda name, data: None if name == "meta.npy" else data)
    old = tmp_path / "old.npz"
    meta = dict(pm.meta, format="voxelplane-reloc-map", format_version=MAP_FORMAT_VERSION + 1, plane_count=len(pm))
    arrays = pm.planes.to_arrays("plane_")
    arrays["observations"] = pm.observations
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(old, **arrays)

    def negative_key(name, data):
        if name != "free_keys.npy":
            return data
        buf = io.BytesIO()
        np.save(buf, np.array([-1, 5, 9], np.int64))  # -1 marks an empty slot of the free-space hash table
        return buf.getvalue()

    negative = tmp_path / "negative_free_key.npz"
    _rewrite(good, negative, negative_key)

    def entry(name, value):  # the entry ``name`` replaced with .npy data of ``value``, or with raw bytes
        def change(item, data):
            if item != name:
                return data
            if isinstance(value, bytes):
                return value
            buf = io.BytesIO()
            np.save(buf, value)
            return buf.getvalue()
        return change

    encrypted = tmp_path / "encrypted_flag.npz"  # one flipped bit: zipfile raised RuntimeError (password required)
    flagged = bytearray(raw)
    flagged[flagged.rfind(b"PK\x01\x02") + 8] ^= 1
    encrypted.write_bytes(bytes(flagged))
    not_npy = tmp_path / "not_npy.npz"  # numpy returned the entry's bytes, and .dtype raised AttributeError
    _rewrite(good, not_npy, entry("observations.npy", b"hello"))
    huge = tmp_path / "huge_header.npz"  # a header declaring 8 TiB: MemoryError
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<i8", "fortran_order": False, "shape": (2**40,)})
    _rewrite(good, huge, entry("observations.npy", b"\x93NUMPY\x01\x00" + header.getvalue()[8:]))
    deep = tmp_path / "deep_meta.npz"  # RecursionError from json
    _rewrite(good, deep, entry("meta.npy", np.frombuffer(b"[" * 100_000 + b"]" * 100_000, np.uint8)))
    gravity_cases = {}
    for k, g in enumerate(([np.nan, 0.0, -1.0], [np.inf, 0.0, 0.0], [0.0, 0.0, -5.0])):
        gravity_cases[tmp_path / f"gravity{k}.npz"] = g  # loaded as no gravity, or scaled to unit length
        _rewrite(good, tmp_path / f"gravity{k}.npz", entry("plane_gravity.npy", np.array(g)))

    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    single = tmp_path / "single.npz"
    with open(single, "wb") as fh:
        np.save(fh, np.zeros(3))

    cases = {
        truncated: "truncated or corrupted",
        garbage: r"not a map file: not an \.npz \(zip\) archive",
        empty: "empty file",
        single: r"not a map file: not an \.npz",
        other: "no 'meta' entry",
        no_meta: "no 'meta' entry",
        old: f"version {MAP_FORMAT_VERSION + 1}",
        negative: r"free_keys: expected sorted unique voxel keys \(>= 0\)",
        tmp_path / "missing.npz": "no such file",
        encrypted: "truncated or corrupted",
        not_npy: "corrupted: entry 'observations' is not an array",
        huge: "truncated or corrupted: cannot read its arrays",
        deep: "truncated or corrupted: cannot read the metadata",
        **{path: r"corrupted: gravity .* is not a direction" for path in gravity_cases},
    }
    for path, pattern in cases.items():
        with pytest.raises(MapFileError, match=pattern) as info:
            load_map(path)
        assert str(path) in str(info.value)
        assert "pickle" not in str(info.value)  # numpy's words for a non-zip file would mislead


def test_a_map_with_broken_planes_is_not_written(tmp_path, living_map):
    """What load_map refuses as corrupted is never written: a map with a NaN normal was saved, then unreadable."""
    from dataclasses import replace

    _, pm = living_map
    normals = pm.planes.normals.copy()
    normals[0] = [np.nan, 0.0, 1.0]
    with pytest.raises(ValueError, match="plane_map.planes: expected finite plane geometry, got non-finite normals"):
        save_map(tmp_path / "bad.npz", PlaneMap(replace(pm.planes, normals=normals), pm.observations))
    assert not (tmp_path / "bad.npz").exists()


def test_plane_map_validates_its_inputs(living_map):
    _, pm = living_map
    with pytest.raises(ValueError, match="observations"):
        PlaneMap(pm.planes, pm.observations[:-1])
    with pytest.raises(ValueError, match="frame 'map'"):
        PlaneMap(pm.planes.transformed(np.eye(4), "cam"), pm.observations)
    with pytest.raises(ValueError, match=r"free_keys: expected sorted unique voxel keys \(>= 0\).* from -3"):
        PlaneMap(pm.planes, pm.observations, free_keys=np.array([-3, 4], np.int64), free_voxel_m=0.2)
    with pytest.raises(ValueError, match="free_keys: expected voxel keys >= 0"):
        build_index(pm.planes, MatchingParams(), free_keys=np.array([-3, 4], np.int64), free_voxel_m=0.2)


def test_free_space_is_carved_in_front_of_surfaces_only():
    from reloc.camera import DepthFrame, Intrinsics
    from reloc.mapping.fusion import voxel_keys

    intr = Intrinsics(fx=50.0, fy=50.0, cx=31.5, cy=23.5, width=64, height=48)
    depth = np.full((48, 64), 3.0, np.float32)  # a wall 3 m ahead of a camera at the origin looking along +z
    builder = MapBuilder(MappingParams(free_space_voxel_m=0.2, free_space_margin_m=0.3, free_space_pixel_stride=4))
    frame = DepthFrame(depth, intr, stamp_ns=0)
    from reloc.planeset import PlaneSet

    builder.add(PlaneSet.empty(gravity=np.array([0.0, 1.0, 0.0])), np.eye(4), frame)  # only the carving matters
    pm = builder.finish()
    free = set(pm.free_keys.tolist())
    assert len(free) > 50 and pm.free_voxel_m == 0.2
    ahead = voxel_keys(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.3, -0.2, 2.4]]), 0.2)
    behind = voxel_keys(np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 3.5], [0.0, 0.0, 5.0]]), 0.2)
    assert all(k in free for k in ahead.tolist())
    assert not any(k in free for k in behind.tolist())


# -- the fusion's bookkeeping kernels against the NumPy they replace (the same figures, to the last bit) ----------


def _random_keys(rng, n, span=40):
    from reloc.mapping.fusion import voxel_keys

    return voxel_keys(rng.integers(-span, span, size=(n, 3)) * 0.1 + 0.05, 0.1)


def test_voxel_sums_match_unique_and_bincount():
    from reloc.mapping import _kernels as K

    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 300):
        pts = rng.normal(size=(n, 3)) * 0.3
        keys = _random_keys(rng, n, span=2)  # at most 4^3 distinct voxels: most hold several points
        uk, inv = np.unique(keys, return_inverse=True)
        ref_sums = np.stack([np.bincount(inv, pts[:, a], len(uk)) for a in range(3)], axis=1)
        ref_counts = np.bincount(inv, minlength=len(uk)).astype(np.float64)
        ko, so, co = np.empty(n, np.int64), np.empty((n, 3)), np.empty(n)
        k = K.voxel_sums(keys, pts, np.argsort(keys, kind="stable"), ko, so, co)
        assert k == len(uk)
        assert np.array_equal(ko[:k], uk) and np.array_equal(so[:k], ref_sums) and np.array_equal(co[:k], ref_counts)
    assert k <= 64  # the last case: 300 points in at most 64 voxels, each voxel's summed in input order


def test_merged_voxel_sums_match_unique_and_bincount_of_both():
    from reloc.mapping import _kernels as K

    rng = np.random.default_rng(1)
    for na, nb in ((0, 5), (5, 0), (30, 40), (200, 3)):
        ka = np.unique(_random_keys(rng, na, span=4)) if na else np.zeros(0, np.int64)
        kb = np.unique(np.concatenate([_random_keys(rng, nb, span=4), ka[: min(na, nb) // 2]]))
        sa, sb = rng.normal(size=(len(ka), 3)), rng.normal(size=(len(kb), 3))
        ca, cb = rng.integers(1, 9, len(ka)).astype(float), rng.integers(1, 9, len(kb)).astype(float)
        keys = np.concatenate([ka, kb])
        uk, inv = np.unique(keys, return_inverse=True)
        vs = np.concatenate([sa, sb])
        ref_sums = np.stack([np.bincount(inv, vs[:, a], len(uk)) for a in range(3)], axis=1)
        ref_counts = np.bincount(inv, np.concatenate([ca, cb]), len(uk))
        size = len(ka) + len(kb)
        ko, so, co = np.empty(size, np.int64), np.empty((size, 3)), np.empty(size)
        k = K.merge_voxel_sums(ka, sa, ca, kb, sb, cb, ko, so, co)
        assert np.array_equal(ko[:k], uk) and np.array_equal(so[:k], ref_sums) and np.array_equal(co[:k], ref_counts)
        assert k == len(ka) + len(kb) - len(np.intersect1d(ka, kb))
    assert len(np.intersect1d(ka, kb)) > 0  # the last case shares voxels (summed a + b)


def test_touching_count_matches_a_search_of_every_neighbour():
    from reloc.mapping import _kernels as K
    from reloc.mapping.fusion import _NEIGHBOUR_OFFSETS, _neighbours

    rng = np.random.default_rng(2)
    for nq, nm in ((1, 1), (50, 80), (300, 20)):
        kq = np.unique(_random_keys(rng, nq, span=6))
        km = np.unique(_random_keys(rng, nm, span=6))
        around = _neighbours(kq)
        pos = np.searchsorted(km, around).clip(max=len(km) - 1)
        expected = int(np.any(km[pos] == around, axis=1).sum())
        assert K.count_touching(kq, km, _NEIGHBOUR_OFFSETS) == expected
    far = np.unique(_random_keys(rng, 20, span=3)) + (np.int64(100) << 42)  # 10 m away along x: no neighbour
    assert K.count_touching(far, km, _NEIGHBOUR_OFFSETS) == 0


def test_touching_both_ways_matches_a_search_of_every_neighbour():
    # The galloping search of the local test: which new voxels touch the map plane (as count_touching counts them) and
    # which map voxels are neighbours of a new one, against numpy's membership test, for planes of very unequal sizes.
    from reloc.mapping import _kernels as K
    from reloc.mapping.fusion import _NEIGHBOUR_OFFSETS, _neighbours

    rng = np.random.default_rng(3)
    touched = []
    for nq, nm, span in ((1, 1, 6), (50, 80, 6), (300, 20, 6), (20, 2000, 12), (400, 400, 4), (1, 500, 2)):
        kq = np.unique(_random_keys(rng, nq, span=span))
        km = np.unique(_random_keys(rng, nm, span=span))
        around = _neighbours(kq)
        hit_q, near_m = np.ones(len(kq), np.bool_), np.ones(len(km), np.bool_)  # cleared by the kernel
        n = K.touching_both_ways(kq, km, _NEIGHBOUR_OFFSETS, hit_q, near_m)
        assert n == K.count_touching(kq, km, _NEIGHBOUR_OFFSETS) == hit_q.sum()
        touched.append(n)
        np.testing.assert_array_equal(hit_q, np.isin(around, km).any(axis=1))
        np.testing.assert_array_equal(near_m, np.isin(km, around.ravel()))
    assert sum(t > 0 for t in touched) >= 4  # most cases touch, so the marks are tested
    far = np.unique(_random_keys(rng, 20, span=3)) + (np.int64(100) << 42)
    assert K.touching_both_ways(far, km, _NEIGHBOUR_OFFSETS, np.empty(len(far), np.bool_), near_m) == 0
    assert not near_m.any()


def test_symmetric_pseudo_inverse_is_numpys_to_the_last_bit():
    from reloc.mapping.fusion import _pinv_symmetric

    rng = np.random.default_rng(3)
    for i in range(300):
        A = rng.normal(size=(4, 4)) * rng.uniform(1e-6, 10, size=4)
        C = A @ A.T
        if i % 3 == 0:  # rank 3, as the (n, d) covariances are (no information along the unit normal)
            v = rng.normal(size=4)
            v /= np.linalg.norm(v)
            P = np.eye(4) - np.outer(v, v)
            C = P @ C @ P
        C = 0.5 * (C + C.T)
        assert np.array_equal(_pinv_symmetric(C, 1e-10), np.linalg.pinv(C, rcond=1e-10, hermitian=True))


def test_fusion_median_is_numpys():
    from reloc.mapping.fusion import _median

    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 4, 17, 100, 101):
        x = np.abs(rng.normal(size=n))
        assert _median(x) == float(np.median(x))
        x[rng.integers(n)] = np.nan
        assert math.isnan(_median(x)) and math.isnan(float(np.median(x)))
    assert _median(np.array([1.0, 1.0, 2.0, 2.0])) == 1.5


def test_stacked_informations_are_each_planes_own():
    from reloc.mapping.fusion import _informations

    rng = np.random.default_rng(5)
    covs = []
    for i in range(7):
        A = rng.normal(size=(4, 4)) * 1e-3
        covs.append(A @ A.T)
    covs[2] = np.zeros((4, 4))  # no information: trace 0
    covs[5] = np.full((4, 4), np.nan)  # unusable
    got = _informations(np.array(covs))
    assert got[2] is None and got[5] is None and _informations(np.zeros((0, 4, 4))) == []
    for i, (g, c) in enumerate(zip(got, covs)):
        if i not in (2, 5):
            assert np.array_equal(g, np.linalg.pinv(0.5 * (c + c.T), rcond=1e-10, hermitian=True))


def test_mapping_params_change_by_name_with_degrees_for_radian_fields():
    base = MappingParams()
    got = base.with_(fuse_max_angle_deg=2, min_observations=4, fuse_max_offset_m=0.02)
    assert got.fuse_max_angle_rad == pytest.approx(math.radians(2.0), abs=1e-15)
    assert (got.min_observations, got.fuse_max_offset_m) == (4, 0.02)
    assert got.fusion.max_angle_rad == got.fuse_max_angle_rad
    assert base.with_() == base
    for change, message in [({"fuse_angle": 2}, "unknown parameter 'fuse_angle'"),
                            ({"min_observations": 2.5}, "min_observations: expected an integer"),
                            ({"fuse_max_angle_deg": 95}, "max_angle_rad: expected in")]:
        with pytest.raises(ValueError, match=message):
            base.with_(**change)


def _one_plane(rect, spacing=0.05):
    from reloc.evaluation.synthetic import planes_from_points

    n = np.asarray(rect.normal, dtype=np.float64)
    return planes_from_points([rect.grid(spacing)], n[None], np.array([-n @ np.asarray(rect.center)]),
                              spacing=spacing, frame="map", gravity=np.array([0.0, 0.0, -1.0]))


@pytest.mark.parametrize("check_bridged", [True, False])
def test_a_plane_touching_two_surfaces_does_not_make_them_one(check_bridged):
    # As in a stereo map of the simulated living room: a TV's face 22 cm in front of its wall (A), a far view's mixed
    # plane tilted 7 deg across the wall (B, seen three times, as the map keeps planes seen three times), and one
    # view's plane (C) within 3 cm of both where they cross. C associates with A and B; they are not one surface.
    # C goes to the one it fits best (B), and A stays as it was.
    from reloc.evaluation.synthetic import Rect

    tilt = math.radians(7.0)
    n_b = (math.cos(tilt), -math.sin(tilt), 0.0)  # B crosses x = 0.20 at y = 1.9
    face = Rect((0.22, 2.75, 1.025), (1, 0, 0), (0, 1, 0), 0.7, 0.325)  # x = 0.22, y 2.05..3.45, z 0.7..1.35
    mixed = Rect((0.20 + 0.75 * math.tan(tilt), 2.65, 1.3), n_b, (math.sin(tilt), math.cos(tilt), 0.0), 1.65, 1.2)
    bridge = Rect((0.20, 1.9, 1.025), (1, 0, 0), (0, 1, 0), 0.15, 0.325)
    a, b, c = _one_plane(face), _one_plane(mixed), _one_plane(bridge)
    # The premises: C is within the association offset (3 cm) of both, and B is not A's surface: each one's samples
    # lie more than twice that from the other's plane in the median.
    p = MappingParams(fuse_check_bridged=check_bridged)
    med = lambda ps, q: np.median(np.abs(ps.sample_points @ q.normals[0] + q.offsets[0]))  # noqa: E731
    assert med(c, a) <= p.fuse_max_offset_m and med(c, b) <= p.fuse_max_offset_m
    assert med(b, a) > 2 * p.fuse_max_offset_m and med(a, b) > 2 * p.fuse_max_offset_m
    assert med(c, b) < med(c, a)
    builder = MapBuilder(p)
    for ps in (a, a, a, b, b, b, c):
        builder.add(ps, np.eye(4))
    pm = builder.finish()
    at_face = np.flatnonzero((pm.planes.normals @ [1, 0, 0] > 0.999) & (np.abs(pm.planes.offsets + 0.22) < 0.01))
    if check_bridged:
        assert len(pm.planes) == 2 and len(at_face) == 1
        i = at_face[0]
        assert pm.observations[i] == 3 and pm.observations[1 - i] == 4
        # The face alone: y 2.05..3.45 by z 0.7..1.35 (0.91 m^2), to one 0.1 m patch along the edges.
        assert pm.planes.areas[i] == pytest.approx(1.4 * 0.65, abs=0.3)
        s = pm.planes.samples_of(i)
        assert np.abs(s @ pm.planes.normals[i] + pm.planes.offsets[i]).max() < 0.03
        # The map's own check: no plane with a quarter of its samples more than 6 cm off it. (B with C leans 1.8 deg
        # toward C, since these synthetic planes all carry the same covariance floor: 11% of its samples are off.)
        cons = pm.consistency()
        assert cons["bent_planes"] == 0 and cons["samples_off_plane_fraction"] < 0.15
    else:
        # Merged: one plane with the tilted plane's 7.9 m^2 of samples, half of them more than 6 cm off it (to 16 cm).
        assert len(pm.planes) == 1
        assert pm.planes.areas[0] > 6.0
        cons = pm.consistency()
        assert cons["bent_planes"] == 1 and cons["bent_area_m2"] == pytest.approx(pm.planes.areas[0])


@pytest.mark.parametrize("check_local", [True, False])
def test_a_door_in_its_niche_does_not_join_a_turned_wall(check_local):
    # As in the tuned Kinect apartment map: a wall (x = 0, y 0..6) whose fused plane has turned 0.9 deg about the
    # vertical through y = 1, so that where its door stands (y 4.1..5.0, 6 cm deep in its niche) the plane lies 4.9 to
    # 6.3 cm behind the wall, by the door. The door's samples are within 0.4 cm of that plane in the median (1.1 cm at
    # most) and touch the wall's: the one-way test lets it join. The wall's own samples around the door lie 6 cm from
    # the door's plane.
    from reloc.evaluation.synthetic import Rect, planes_from_points

    gravity = np.array([0.0, 0.0, -1.0])
    theta = math.radians(0.9)
    wall_pts = Rect((0.0, 3.0, 1.25), (1, 0, 0), (0, 1, 0), 3.0, 1.25).grid(0.05)
    wall_pts = wall_pts[~((wall_pts[:, 1] > 4.1) & (wall_pts[:, 1] < 5.0) & (wall_pts[:, 2] < 2.0))]
    wall = planes_from_points([wall_pts], np.array([[math.cos(theta), math.sin(theta), 0.0]]),
                              np.array([-math.sin(theta)]), spacing=0.05, frame="map", gravity=gravity)
    door = _one_plane(Rect((-0.06, 4.55, 1.0), (1, 0, 0), (0, 1, 0), 0.45, 1.0))
    dist = np.abs(door.sample_points @ wall.normals[0] + wall.offsets[0])
    assert np.median(dist) < 0.005 and dist.max() < 0.012  # the door passes the test against the wall's plane
    builder = MapBuilder(MappingParams(fuse_check_local=check_local))
    for ps in (wall, wall, wall, door, door, door):
        builder.add(ps, np.eye(4))
    pm = builder.finish()
    if check_local:
        # Two planes, each seen three times: the door where it stands (x = -0.06) and the wall as it was fused.
        assert len(pm) == 2 and list(pm.observations) == [3, 3]
        i = int(np.argmax(pm.planes.areas))
        assert pm.planes.normals[i] @ wall.normals[0] == pytest.approx(1.0, abs=1e-9)
        assert pm.planes.offsets[i] == pytest.approx(wall.offsets[0], abs=1e-9)
        assert pm.planes.offsets[1 - i] == pytest.approx(0.06, abs=1e-6)
        assert pm.planes.normals[1 - i] @ np.array([1.0, 0, 0]) == pytest.approx(1.0, abs=1e-9)
    else:
        # One plane of six views holding both surfaces' samples (the wall's 13.2 m^2 and the door's 1.8).
        assert len(pm) == 1 and pm.observations[0] == 6
        assert pm.planes.areas[0] > 14.0


@pytest.mark.parametrize("max_far_fraction, check_local", [(0.25, True), (0.25, False), (1.0, True), (1.0, False)])
def test_a_plane_of_two_layers_does_not_join_a_surface(max_far_fraction, check_local):
    # A far stereo view's plane mostly on a TV's face and partly on the wall 22 cm behind it (37.5 % of its samples),
    # fitted between the two (x = 0.1375): its samples' median offset from the face's map plane is 0, so only the share
    # of far samples tells it is not the face. (The test is one-way, the new plane's samples against the map plane: a
    # two-layer plane already in the map, fitted on one of its layers, still takes in a plane on that layer.) The
    # local test, the face's own samples against the new plane (8 cm off it), tells it as well.
    from reloc.evaluation.synthetic import Rect, planes_from_points

    face = _one_plane(Rect((0.22, 2.75, 1.025), (1, 0, 0), (0, 1, 0), 0.7, 0.325))  # y 2.05..3.45
    on_face = Rect((0.22, 3.7, 1.025), (1, 0, 0), (0, 1, 0), 0.25, 0.325).grid(0.05)  # y 3.45..3.95, touching it
    on_wall = Rect((0.0, 4.35, 1.025), (1, 0, 0), (0, 1, 0), 0.15, 0.325).grid(0.05)  # y 4.2..4.5, 22 cm behind
    mixed = planes_from_points([np.concatenate([on_face, on_wall])], np.array([[1.0, 0, 0]]), np.array([-0.1375]),
                               spacing=0.05, frame="map", gravity=np.array([0.0, 0.0, -1.0]))
    far = np.abs(mixed.sample_points[:, 0] - 0.22) > 0.06
    assert far.mean() == pytest.approx(0.375, abs=0.03)
    builder = MapBuilder(MappingParams(fuse_max_far_fraction=max_far_fraction, fuse_check_local=check_local))
    for ps in (face, face, face, mixed, mixed, mixed):
        builder.add(ps, np.eye(4))
    pm = builder.finish()
    off = [np.abs(pm.planes.samples_of(i) @ pm.planes.normals[i] + pm.planes.offsets[i]).max() for i in range(len(pm))]
    if max_far_fraction < 1 or check_local:
        # The face alone, with its own samples (within 1 mm). The two-layer plane does not even fuse with itself (its
        # samples lie 8-14 cm from its own plane), so seen once each time it is dropped as the map drops such planes.
        assert len(pm) == 1 and pm.observations[0] == 3 and off[0] < 1e-3
        assert pm.planes.offsets[0] == pytest.approx(-0.22, abs=1e-6)
    else:
        # The face takes it in, moves toward the wall (x = 0.187 after the first), and holds the wall's samples.
        assert len(pm) == 1 and pm.observations[0] >= 4 and off[0] > 0.15
