"""The simulator's honesty: the renderer against a slow reference, labels against the ground-truth planes, noise
within its model's bound, determinism."""

from __future__ import annotations

import numpy as np
import pytest

import sim
from sim.cameras import preset
from sim.ground_truth import planes_in_camera, visible_planes, visible_planes_with_ids
from sim.noise import make_noise
from sim.reference import reference_render
from sim.render import render
from sim.scenes import SCENE_NAMES, make_scene
from sim.trajectories import pose_from, random_views

SMALL = preset("kinect").scaled(160, 120)


def _rays(intr):
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    return np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(u.shape)], axis=-1)


@pytest.mark.parametrize("name", ["living_room", "office"])
def test_renderer_matches_numpy_reference(name):
    scene = make_scene(name)
    intr = preset("kinect").scaled(64, 48)
    poses = random_views(scene, 3, seed=5) + 0.0
    # Also a camera close to a wall, so polygons are clipped by the near plane.
    poses = np.concatenate([poses, pose_from(0.4, 0.8, 1.2, np.radians(200), np.radians(-35))[None]])
    for T in poses:
        depth, labels = render(scene, intr, T)
        ref_d, ref_l = reference_render(scene, intr, T)
        assert np.array_equal(np.isnan(depth), np.isnan(ref_d))
        np.testing.assert_allclose(depth, ref_d, rtol=1e-5, atol=1e-6, equal_nan=True)
        # Labels may differ only on ties (pixel centres on an edge shared by polygons of equal depth).
        differ = labels != ref_l
        assert differ.mean() < 0.01
        np.testing.assert_allclose(depth[differ], ref_d[differ], rtol=1e-5)


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_closed_scenes_have_no_holes(name):
    """Every ray from inside a scene hits a surface: no crack between polygons, nothing open to the void."""
    scene = make_scene(name)
    intr = preset("wide-tof").scaled(64, 48)
    for T in random_views(scene, 4, seed=2, probe=intr, min_planes=1, min_median_depth_m=0.5):
        depth, _ = render(scene, intr, T)
        assert np.isfinite(depth).all()


def _true_depth(frame, scene):
    """Depth each labelled pixel would have on its ground-truth plane; NaN elsewhere."""
    n_cam, d_cam = planes_in_camera(scene, frame.T_world_cam)
    rows = np.zeros(scene.plane_ids.max() + 1, np.int64)
    rows[scene.plane_ids] = np.arange(scene.n_planes)
    lab = frame.labels
    r = rows[lab]
    ray = _rays(frame.intrinsics)
    z = -d_cam[r] / np.einsum("hwk,hwk->hw", ray, n_cam[r])
    return np.where(lab > 0, z, np.nan)


def test_labelled_pixels_back_project_onto_their_plane_exactly():
    scene = make_scene("living_room")
    frames = sim.simulate_frames(scene, "handheld", 4, noise="none", camera=SMALL, seed=3)
    for f in frames:
        lab = f.labels > 0
        assert lab.mean() > 0.5
        z_true = _true_depth(f, scene)
        # Float32 storage is the only error.
        np.testing.assert_allclose(f.depth_m[lab], z_true[lab], rtol=2e-7, atol=1e-6)
        # The back-projected point lies on its plane.
        n_cam, d_cam = planes_in_camera(scene, f.T_world_cam)
        v, u = np.nonzero(lab)
        rows = np.array([scene.index_of(i) for i in f.labels[v, u][:200]])
        p = _rays(f.intrinsics)[v[:200], u[:200]] * f.depth_m[v[:200], u[:200], None]
        dist = np.abs(np.einsum("nk,nk->n", p, n_cam[rows]) + d_cam[rows])
        assert dist.max() < 1e-5


@pytest.mark.parametrize("noise", ["kinect", "stereo", "tof"])
def test_labelled_pixels_within_noise_bound(noise):
    scene = make_scene("office")
    model = make_noise(noise)
    frames = sim.simulate_frames(scene, "random", 3, noise=noise, camera=SMALL, seed=4)
    z_all, err_all, sig_all = [], [], []
    for f in frames:
        lab = f.labels > 0
        assert np.isfinite(f.depth_m[lab]).all()
        z_true = _true_depth(f, scene)
        radius = model.radius_map(f.intrinsics)
        bound = model.max_error_m(z_true, radius, f.intrinsics.fx, n_sigma=6.0)
        err = f.depth_m - z_true
        assert np.all(np.abs(err[lab]) <= bound[lab])
        sig = model.sigma_m(z_true, radius, f.intrinsics.fx)
        z_all.append(z_true[lab])
        err_all.append(err[lab])
        sig_all.append(sig[lab])
        # Range limits hold for every measurement.
        d = f.depth_m[np.isfinite(f.depth_m)]
        assert d.min() >= model.min_range_m and d.max() <= model.max_range_m
    err, sig = np.concatenate(err_all), np.concatenate(sig_all)
    if noise in ("kinect", "tof"):
        # The residuals follow the stated Gaussian: standardised spread 1 within sampling error.
        s = np.std(err / sig)
        assert 0.95 < s < 1.05
        assert abs(np.mean(err / sig)) < 0.05
    else:
        # Stereo: the depth error is disparity noise plus quantisation, so it grows as z^2.
        z = np.concatenate(z_all)
        near, far = z < np.percentile(z, 30), z > np.percentile(z, 70)
        assert np.std(err[far]) > 2.0 * np.std(err[near])


def test_flying_pixel_candidates_are_the_far_side_of_every_jump():
    """The kernel's candidates against the same test in NumPy (a pixel whose nearest 4-neighbour is nearer by more
    than ``discontinuity_rel`` of its depth; NaN is no surface), on a rendered frame with holes cut into it."""
    from sim import _noise_kernels as K

    depth, _ = render(make_scene("office"), SMALL, pose_from(4.5, 3.5, 1.6, np.radians(-140), np.radians(-20)))
    z = np.ascontiguousarray(depth, dtype=np.float32)
    z[10:14, 20:60] = np.nan
    z[:, -1] = np.nan
    model = make_noise("kinect")
    out = np.zeros(z.shape, np.bool_)
    n = K.flying_candidates(z, float(model.discontinuity_rel), out)
    near = model.nearer_neighbour(z)
    want = np.isfinite(z) & (near < z.astype(np.float64) * (1.0 - model.discontinuity_rel))
    assert n == want.sum() > 100
    np.testing.assert_array_equal(out, want)


def test_noise_has_dropouts_and_flying_pixels():
    scene = make_scene("office")
    intr = SMALL
    T = pose_from(4.5, 3.5, 1.6, np.radians(-140), np.radians(-20))
    depth, labels = render(scene, intr, T)
    model = make_noise("kinect", missing_fraction=0.05, flying_probability=1.0)
    noisy, lab = model.apply(depth, labels, intr, np.random.default_rng(0))
    near = model.nearer_neighbour(depth.astype(np.float64))
    jump = np.isfinite(depth) & (near < depth * (1 - model.discontinuity_rel))
    # Dropouts: 5 % of the pixels well inside the range (binomial, 4 sigma).
    inside = np.isfinite(depth) & (depth > model.min_range_m + 0.1) & (depth < model.max_range_m - 0.5) & ~jump
    lost = ~np.isfinite(noisy[inside])
    p, n = 0.05, inside.sum()
    assert n > 5000 and abs(lost.mean() - p) < 4 * np.sqrt(p * (1 - p) / n)
    # Beyond the range: nothing.
    assert not np.isfinite(noisy[np.isfinite(depth) & (depth > model.max_range_m + 0.5)]).any()
    # Flying pixels: valid, unlabelled, strictly between the two surfaces of a discontinuity.
    cand = jump & np.isfinite(noisy)
    assert cand.sum() > 20
    assert np.all(lab[cand] == 0)
    assert np.all((noisy[cand] > near[cand]) & (noisy[cand] < depth[cand]))


def test_same_seed_identical_frames_other_seed_differs():
    a = sim.simulate_frames("living_room", "robot", 3, noise="kinect", camera=SMALL, seed=7)
    b = sim.simulate_frames("living_room", "robot", 3, noise="kinect", camera=SMALL, seed=7)
    c = sim.simulate_frames("living_room", "robot", 3, noise="kinect", camera=SMALL, seed=8)
    for fa, fb in zip(a, b):
        assert np.array_equal(fa.depth_m, fb.depth_m, equal_nan=True)
        assert np.array_equal(fa.labels, fb.labels)
        assert np.array_equal(fa.T_world_cam, fb.T_world_cam)
        assert fa.stamp_ns == fb.stamp_ns
    assert not np.allclose(a[0].T_world_cam, c[0].T_world_cam)
    assert not np.array_equal(a[0].depth_m, c[0].depth_m, equal_nan=True)
    # Same poses, other seed: the noise differs.
    d = sim.simulate_frames("living_room", np.stack([f.T_world_cam for f in a]), noise="kinect", camera=SMALL, seed=8)
    assert not np.array_equal(a[0].depth_m, d[0].depth_m, equal_nan=True)
    assert np.array_equal(a[0].depth_m, sim.make_camera("living_room", "robot", 3, camera=SMALL, seed=7)[0].depth_m,
                          equal_nan=True)


def test_frames_carry_pose_gravity_and_stamps():
    frames = sim.simulate_frames("office", "handheld", 4, noise="none", camera=SMALL, seed=1)
    for i, f in enumerate(frames):
        R = f.T_world_cam[:3, :3]
        np.testing.assert_allclose(f.gravity_cam, R.T @ [0, 0, -1], atol=1e-12)
        assert f.seq == i and f.pose_source == "groundtruth"
        assert f.labels.dtype == np.int32
    stamps = np.array([f.stamp_ns for f in frames])
    np.testing.assert_array_equal(np.diff(stamps), [33333333, 33333334, 33333333])


def test_visible_planes_ground_truth():
    scene = make_scene("living_room")
    f = sim.simulate_frames(scene, "random", 1, noise="kinect", camera=SMALL, seed=11)[0]
    ps, ids = visible_planes_with_ids(f, scene, min_pixels=30)
    assert len(ps) >= 3 and ps.frame == "cam"
    np.testing.assert_allclose(ps.gravity, f.gravity_cam)
    n_cam, d_cam = planes_in_camera(scene, f.T_world_cam)
    for k, pid in enumerate(ids):
        row = scene.index_of(int(pid))
        # Exact plane, oriented toward the camera (the origin is on the positive side).
        assert ps.offsets[k] > 0
        assert abs(abs(ps.normals[k] @ n_cam[row]) - 1) < 1e-12
        np.testing.assert_allclose(abs(ps.offsets[k]), abs(d_cam[row]), atol=1e-12)
        assert ps.counts[k] == np.count_nonzero(f.labels == pid)
        assert np.count_nonzero(ps.labels == k) == ps.counts[k]
        # Centroid and samples lie on the plane; the radius covers the samples.
        assert abs(ps.normals[k] @ ps.centroids[k] + ps.offsets[k]) < 1e-9
        s = ps.samples_of(k).astype(np.float64)
        assert np.abs(s @ ps.normals[k] + ps.offsets[k]).max() < 1e-5
        assert np.linalg.norm(s - ps.centroids[k], axis=1).max() <= ps.radii[k] + 1e-5
        np.testing.assert_allclose(ps.sums[k] / ps.counts[k], ps.centroids[k], atol=1e-9)
        # Covariance: symmetric positive semi-definite, no variance along the unit-norm constraint.
        C = ps.covariances[k]
        assert np.allclose(C, C.T) and np.linalg.eigvalsh(C).min() > -1e-15
        u = np.append(ps.normals[k], 0.0)
        assert abs(u @ C @ u) < 1e-12
    # The floor, seen from above, has its normal straight up: against gravity.
    floor = np.flatnonzero(ids == scene.plane_ids[list(scene.plane_kinds).index("floor")])
    if floor.size:
        np.testing.assert_allclose(ps.normals[floor[0]], -f.gravity_cam, atol=1e-9)
    assert len(visible_planes(f, scene, min_pixels=10)) >= len(ps)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="name"):
        make_scene("castle")
    with pytest.raises(ValueError, match="name"):
        preset("webcam")
    with pytest.raises(ValueError, match="name"):
        make_noise("lidar")
    with pytest.raises(ValueError, match="T_world_cam"):
        render(make_scene("office"), SMALL, np.eye(3))
    with pytest.raises(ValueError, match="trajectory"):
        sim.simulate_frames("office", "teleport", 2, camera=SMALL)


def test_each_noise_model_names_the_law_extraction_should_assume():
    from sim.noise import make_noise

    assert make_noise("kinect").extraction_law(525.0) == ("kinect", 1.425e-3)
    model, c = make_noise("stereo").extraction_law(-400.0)  # the sign of a mirrored focal length does not matter
    assert model == "stereo" and abs(c - 0.08 / (400.0 * 0.075)) < 1e-15
    model, c = make_noise("tof").extraction_law(500.0)
    # sigma = a + b z, folded into c z at 2 m: c = b + a / 2.
    assert model == "tof" and abs(c - (2e-3 + 2e-3 / 2)) < 1e-15
    assert make_noise("none").extraction_law(500.0) is None
