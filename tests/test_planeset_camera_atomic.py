"""PlaneSet moves consistently with the transforms; intrinsics and depth frames validate; atomic writes."""

from __future__ import annotations

import os
import stat
from dataclasses import replace

import numpy as np
import pytest

from reloc import transforms as tf
from reloc.atomic import atomic_write, atomic_write_text
from reloc.camera import DepthFrame, Intrinsics
from reloc.planeset import PlaneSet


def planeset_from_points(groups, frame="cam"):
    """Build a PlaneSet from lists of exact coplanar points (a slow, obviously-correct reference)."""
    rows = []
    for pts in groups:
        c = pts.mean(0)
        _, _, vt = np.linalg.svd(pts - c)
        n = vt[2]
        if n @ (-c) < 0:  # toward the origin (sensor)
            n = -n
        rows.append((n, -n @ c, c, len(pts), np.linalg.norm(pts - c, axis=1).max(), pts.sum(0), pts.T @ pts))
    ptr = np.concatenate([[0], np.cumsum([len(g) for g in groups])])
    return PlaneSet(
        normals=np.array([r[0] for r in rows]), offsets=np.array([r[1] for r in rows]),
        centroids=np.array([r[2] for r in rows]), counts=np.array([r[3] for r in rows]),
        radii=np.array([r[4] for r in rows]), areas=np.ones(len(rows)),
        covariances=np.tile(np.diag([1e-4, 2e-4, 3e-4, 1e-3]), (len(rows), 1, 1)),
        sums=np.array([r[5] for r in rows]), scatters=np.array([r[6] for r in rows]),
        sample_points=np.concatenate(groups).astype(np.float32), sample_ptr=ptr, frame=frame,
        gravity=np.array([0.0, 1.0, 0.0]),
    )


def test_planeset_transformed_matches_recomputation():
    rng = np.random.default_rng(3)
    floor = np.c_[rng.uniform(-1, 1, 50), np.full(50, 1.2), rng.uniform(1, 3, 50)]
    wall = np.c_[rng.uniform(-1, 1, 40), rng.uniform(-1, 1, 40), np.full(40, 3.0)]
    ps = planeset_from_points([floor, wall])
    T = tf.transform_from_rotation_translation(tf.rotation_from_axis_angle([0.3, -0.2, 1.0]), [1.0, -2.0, 0.5])
    moved = ps.transformed(T, "map")
    ref = planeset_from_points([tf.apply(T, floor), tf.apply(T, wall)])
    # The reference re-orients toward the new origin, so compare normals up to sign.
    np.testing.assert_allclose(np.abs(np.sum(moved.normals * ref.normals, 1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(moved.centroids, ref.centroids, atol=1e-9)
    np.testing.assert_allclose(moved.sums, ref.sums, atol=1e-8)
    np.testing.assert_allclose(moved.scatters, ref.scatters, atol=1e-7)
    np.testing.assert_allclose(moved.radii, ref.radii)
    np.testing.assert_allclose(moved.sample_points, tf.apply(T, np.concatenate([floor, wall])), atol=1e-5)
    # Each moved plane still contains its moved points.
    for i, pts in enumerate([floor, wall]):
        np.testing.assert_allclose(tf.apply(T, pts) @ moved.normals[i] + moved.offsets[i], 0.0, atol=1e-9)
    np.testing.assert_allclose(moved.gravity, T[:3, :3] @ [0, 1, 0])
    # The (n, d) covariance moves by a linear map, so moving there and back restores it exactly.
    back = moved.transformed(tf.invert(T), "cam")
    np.testing.assert_allclose(back.covariances, ps.covariances, atol=1e-12)
    np.testing.assert_allclose(back.normals, ps.normals, atol=1e-12)


def test_planeset_subset_and_arrays_round_trip():
    rng = np.random.default_rng(0)
    groups = [np.c_[rng.uniform(0, 1, k), rng.uniform(0, 1, k), np.full(k, 2.0 + i)] for i, k in enumerate([5, 7, 3])]
    ps = planeset_from_points(groups)
    sub = ps.subset(np.array([2, 0]))
    assert len(sub) == 2
    for none in ([], np.zeros(0, np.int64), np.zeros(3, bool)):  # [] reads as float: it raised IndexError
        empty = ps.subset(none)
        assert len(empty) == 0 and empty.sample_ptr.tolist() == [0] and empty.sample_points.shape == (0, 3)
    np.testing.assert_array_equal(sub.samples_of(0), groups[2].astype(np.float32))
    np.testing.assert_array_equal(sub.samples_of(1), groups[0].astype(np.float32))
    arrays = ps.to_arrays("m_")
    back = PlaneSet.from_arrays(arrays, "m_", frame="cam")
    for name in ("normals", "offsets", "centroids", "counts", "covariances", "sample_points", "sample_ptr", "gravity"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ps, name))
    assert len(PlaneSet.empty()) == 0
    # The gravity's tolerance goes with it; arrays written before it existed read as measured gravity (0).
    tilted = replace(ps, gravity_tolerance_rad=0.35)
    assert PlaneSet.from_arrays(tilted.to_arrays("m_"), "m_").gravity_tolerance_rad == 0.35
    assert tilted.subset([1]).gravity_tolerance_rad == 0.35
    assert tilted.transformed(tf.exp_se3(np.r_[0.1, 0.2, 0.3, 0.1, -0.2, 0.3]), "map").gravity_tolerance_rad == 0.35
    del arrays["m_gravity_tolerance_rad"]
    assert PlaneSet.from_arrays(arrays, "m_").gravity_tolerance_rad == 0.0
    for bad in (-0.1, 2.0, float("nan"), "0.1"):
        with pytest.raises(ValueError, match=r"PlaneSet.gravity_tolerance_rad: expected a number in \[0, pi/2\]"):
            replace(ps, gravity_tolerance_rad=bad)
    # The cameras' positions go with the planes: kept by subsets, moved by transforms, saved only when known.
    seen = replace(ps, viewpoints=[[0.0, 0.0, 0.0], [0.5, 0.0, -1.0]])
    T = tf.exp_se3(np.r_[0.1, 0.2, 0.3, 0.1, -0.2, 0.3])
    np.testing.assert_allclose(seen.transformed(T, "map").viewpoints, tf.apply(T, seen.viewpoints), atol=1e-12)
    np.testing.assert_array_equal(seen.subset([1]).viewpoints, seen.viewpoints)
    np.testing.assert_array_equal(PlaneSet.from_arrays(seen.to_arrays("m_"), "m_").viewpoints, seen.viewpoints)
    assert "m_viewpoints" not in ps.to_arrays("m_")
    assert PlaneSet.from_arrays(ps.to_arrays("m_"), "m_").viewpoints is None
    for bad in ([1.0, 2.0, 3.0], [[0.0, 0.0, float("inf")]], np.zeros((2, 2))):
        with pytest.raises(ValueError, match=r"PlaneSet.viewpoints: expected a finite \(V, 3\) array"):
            replace(ps, viewpoints=bad)


def test_planeset_shape_errors():
    ps = PlaneSet.empty()
    with pytest.raises(ValueError, match=r"PlaneSet.offsets: expected shape \(0,\), got \(2,\)"):
        PlaneSet(**{**{k: getattr(ps, k) for k in ("normals", "centroids", "counts", "radii", "areas",
                                                   "covariances", "sums", "scatters", "sample_points",
                                                   "sample_ptr")}, "offsets": np.zeros(2)})


def test_planeset_gravity_is_normalised_or_refused():
    ps = PlaneSet.empty()
    fields = {k: getattr(ps, k) for k in ("normals", "offsets", "centroids", "counts", "radii", "areas", "covariances",
                                          "sums", "scatters", "sample_points", "sample_ptr")}
    np.testing.assert_allclose(PlaneSet(**fields, gravity=[0.0, 0.0, -9.81]).gravity, [0.0, 0.0, -1.0])
    for bad in ([0.0, 0.0, 0.0], [np.nan, 0.0, -1.0], [np.inf, 0.0, 0.0], [1e300, 1e300, 0.0]):
        with pytest.raises(ValueError, match="PlaneSet.gravity: expected a finite non-zero 3-vector"):
            PlaneSet(**fields, gravity=bad)


def test_intrinsics_validation_and_scaling():
    K = Intrinsics(fx=500.0, fy=-480.0, cx=319.5, cy=239.5, width=640, height=480, depth_scale=5000.0)
    half = K.scaled(320, 240)
    assert (half.fx, half.fy, half.cx, half.cy) == (250.0, -240.0, 159.5, 119.5)
    with pytest.raises(ValueError, match="Intrinsics.width: expected a positive integer"):
        Intrinsics(500.0, 500.0, 1.0, 1.0, 0, 10)
    with pytest.raises(ValueError, match="Intrinsics.fx: expected > 0"):
        Intrinsics(-500.0, 500.0, 1.0, 1.0, 10, 10)
    with pytest.raises(ValueError, match="missing keys"):
        Intrinsics.from_dict({"fx": 1.0}, "camera.yaml")
    assert Intrinsics.from_dict(K.as_dict()) == K
    # A calibration read as numpy scalars (float32 from a device, int64 sizes) is taken, as Python numbers; a bool is
    # not a number here.
    K32 = Intrinsics(*np.float32([525.0, 525.0, 319.5, 239.5]), np.int64(640), np.int64(480), np.float32(1000.0))
    assert K32 == Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480, 1000.0)
    assert all(type(getattr(K32, f)) is float for f in ("fx", "fy", "cx", "cy", "depth_scale"))
    assert type(K32.width) is int and hash(K32) == hash(Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480, 1000.0))
    with pytest.raises(ValueError, match="Intrinsics.fx: expected a finite number, got True"):
        Intrinsics(True, 500.0, 1.0, 1.0, 10, 10)


def test_depth_frame_validation():
    K = Intrinsics(500.0, 500.0, 2.0, 2.0, 4, 3)
    f = DepthFrame(np.ones((3, 4), np.float64), K, stamp_ns=np.int64(5), gravity_cam=[0, 2, 0])
    assert f.depth_m.dtype == np.float32 and f.stamp_ns == 5
    np.testing.assert_allclose(f.gravity_cam, [0, 1, 0])
    with pytest.raises(ValueError, match=r"does not match intrinsics"):
        DepthFrame(np.ones((4, 4), np.float32), K, stamp_ns=0)
    with pytest.raises(ValueError, match="stamp_ns: expected an integer"):
        DepthFrame(np.ones((3, 4), np.float32), K, stamp_ns=1.5)
    with pytest.raises(ValueError, match="gravity_cam"):
        DepthFrame(np.ones((3, 4), np.float32), K, stamp_ns=0, gravity_cam=[0, 0, 0])
    with pytest.raises(ValueError, match="T_world_cam"):
        DepthFrame(np.ones((3, 4), np.float32), K, stamp_ns=0, T_world_cam=np.zeros((4, 4)))
    d = np.array([[1, 0, np.nan, -1], [np.inf, 2, 2, 2], [2, 2, 2, 2]], np.float32)
    assert DepthFrame(d, K, stamp_ns=0).valid_mask.sum() == 8


def test_depth_frame_pose_source_has_one_spelling():
    K = Intrinsics(500.0, 500.0, 2.0, 2.0, 4, 3)
    d = np.ones((3, 4), np.float32)
    for source in ("groundtruth", "odometry", "none"):
        assert DepthFrame(d, K, stamp_ns=0, pose_source=source).pose_source == source
    for other in ("gt", "ground_truth"):  # one spelling, the one the readers, the recorder and the live loop use
        with pytest.raises(ValueError, match=r"DepthFrame.pose_source: expected one of groundtruth, odometry, none, "
                                             rf"got '{other}'"):
            DepthFrame(d, K, stamp_ns=0, pose_source=other)


def test_atomic_write_names_the_file_in_the_way_of_its_folder(tmp_path):
    (tmp_path / "out").write_text("")
    with pytest.raises(NotADirectoryError, match=r"cannot make the folder of .*x.txt: .*out is a file, not a folder"):
        atomic_write_text(tmp_path / "out" / "sub" / "x.txt", "x")
    assert (tmp_path / "out").read_text() == ""


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "map.npz"
    atomic_write_text(target, "old")
    with pytest.raises(RuntimeError):
        with atomic_write(target, "w") as fh:
            fh.write("half-writ")
            raise RuntimeError("crash mid-write")
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["map.npz"]  # no temporary left behind
    atomic_write_text(target, "new")
    assert target.read_text() == "new"


def test_atomic_write_gives_normal_permissions_and_keeps_existing_ones(tmp_path):
    old = os.umask(0o027)
    try:
        fresh = tmp_path / "picture.png"
        atomic_write_text(fresh, "x")
        assert stat.S_IMODE(fresh.stat().st_mode) == 0o640  # 0o666 less the umask, not mkstemp's 0o600
        kept = tmp_path / "kept.json"
        kept.write_text("old")
        os.chmod(kept, 0o604)
        atomic_write_text(kept, "new")
        assert stat.S_IMODE(kept.stat().st_mode) == 0o604 and kept.read_text() == "new"
    finally:
        os.umask(old)


def test_atomic_write_interrupted_just_after_creating_its_temporary_leaves_nothing(tmp_path, monkeypatch):
    # Ctrl-C landing right after the temporary file exists (CI once found one left behind by `reloc record`).
    import reloc.atomic as atomic

    target = tmp_path / "map.npz"
    target.write_bytes(b"old")
    real_open = os.open
    opened = []

    def open_then_interrupt(path, flags, mode=0o777, **kw):
        fd = real_open(path, flags, mode, **kw)
        if str(path).endswith(".tmp"):
            opened.append(fd)
            raise KeyboardInterrupt
        return fd

    monkeypatch.setattr(atomic.os, "open", open_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        atomic.atomic_write_bytes(target, b"new")
    monkeypatch.undo()
    for fd in opened:
        os.close(fd)
    assert len(opened) == 1 and target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.npz"]
