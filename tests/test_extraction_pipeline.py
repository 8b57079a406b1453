"""Depth frames and point clouds to plane sets, against the simulator's ground truth and exact identities."""

from __future__ import annotations

import numpy as np
import pytest

from reloc.camera import DepthFrame, Intrinsics
from reloc.extraction import ExtractionParams, PlaneExtractor, extract_planes, extract_planes_from_points
from reloc.planes import plane_errors

K = Intrinsics(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)


def _box_room(noise_coeff=1.425e-3, seed=0, R=None):
    """Depth of a camera at the origin inside a 4 x 2.6 x 6 m box, Kinect noise along the rays; labels 1..6 and
    the six planes (normal toward the camera, offset) in the camera frame."""
    rng = np.random.default_rng(seed)
    R = np.eye(3) if R is None else R
    centre, half = np.array([0.3, -0.2, 2.0]), np.array([2.0, 1.3, 3.0])
    v, u = np.mgrid[0:K.height, 0:K.width]
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1)
    planes, best, labels = [], np.full(u.shape, np.inf), np.zeros(u.shape, np.int32)
    for ax in range(3):
        for s in (-1, 1):
            n = R @ (-s * np.eye(3)[ax])
            d = -n @ (R @ (centre + s * half[ax] * np.eye(3)[ax]))
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -d / (rays @ n)
            hit = (t > 0) & (t < best)
            best[hit], labels[hit] = t[hit], len(planes) + 1
            planes.append(np.r_[n, d])
    depth = best + rng.normal(size=best.shape) * noise_coeff * best**2
    return depth.astype(np.float32), labels, np.array(planes)


def _rot(axis, angle):
    from reloc.transforms import rotation_from_axis_angle

    a = np.asarray(axis, float)
    return rotation_from_axis_angle(a / np.linalg.norm(a) * angle)


def _matches(ps, labels, planes):
    """For every ground-truth plane seen on > 2 % of the image: the extracted plane with the most of its pixels,
    and that plane's angle (deg) and offset (m) errors."""
    out = {}
    for k in range(1, len(planes) + 1):
        if (labels == k).sum() < 0.02 * labels.size:
            continue
        overlap = [((ps.labels == i) & (labels == k)).sum() for i in range(len(ps))]
        if not overlap or max(overlap) == 0:
            out[k] = None
            continue
        i = int(np.argmax(overlap))
        out[k] = (i, *plane_errors(np.r_[ps.normals[i], ps.offsets[i]], planes[k - 1]))
    return out


def plane_angles(a, b):
    """Angle (deg) between each plane of ``a`` and the closest-normal plane of ``b``."""
    return np.degrees(np.arccos(np.clip((a.normals @ b.normals.T).max(axis=1), -1, 1)))


def test_box_room_planes_are_recovered_with_their_set_filled():
    depth, labels, planes = _box_room(R=_rot([0.3, 1.0, 0.2], 0.5))
    frame = DepthFrame(depth, K, stamp_ns=0, gravity_cam=np.array([0.0, 0.9, 0.1]))
    res = extract_planes(frame, ExtractionParams())
    ps = res.planes
    # Kinect noise at 2-5 m with 10^4 points per wall: a weighted fit is good to ~0.01 deg / 0.5 mm.
    m = _matches(ps, labels, planes)
    assert m and all(v is not None for v in m.values())
    for k, (i, ang, off) in m.items():
        assert ang < 0.1 and off < 0.005, (k, ang, off)
    assert len(ps) == len(m)  # no spurious planes
    # The set is complete and consistent.
    assert np.allclose(np.linalg.norm(ps.normals, axis=1), 1.0)
    assert np.all(ps.offsets > 0)  # normals toward the camera at the origin
    assert np.allclose(ps.centroids, ps.sums / ps.counts[:, None])
    assert np.allclose(ps.normals @ np.ones(3) * 0 + np.einsum("ij,ij->i", ps.normals, ps.centroids) + ps.offsets,
                       0.0, atol=0.01)
    assert np.all(np.diff(ps.counts) <= 0)  # largest first
    for i in range(len(ps)):
        assert ps.counts[i] == (ps.labels == i).sum()
        # Samples are cell means of supporting points: on the plane within the noise band.
        pts_i = ps.samples_of(i)
        band = 4 * 1.5 * 1.425e-3 * pts_i[:, 2].astype(float) ** 2 + 0.01
        assert len(pts_i) > 10 and np.all(np.abs(pts_i @ ps.normals[i] + ps.offsets[i]) < band)
        assert np.all(np.linalg.eigvalsh(ps.covariances[i]) > -1e-15)
        # Radius and area of a wall patch of known pixels: the area is at most the patch's bounding extent.
        assert 0.0 < ps.areas[i] <= np.pi * ps.radii[i] ** 2 + 0.1
    assert np.allclose(ps.gravity, np.array([0.0, 0.9, 0.1]) / np.linalg.norm([0.0, 0.9, 0.1]))
    assert set(res.timings_ms) >= {"backproject", "voxelize", "fit", "weight", "merge", "finalize", "total"}
    assert ps.labels.shape == depth.shape and ps.labels.dtype == np.int32


def test_simulated_frames_within_noise_model_tolerance():
    sim = pytest.importorskip("sim")
    from sim.ground_truth import visible_planes_with_ids
    from sim.scenes import make_scene

    scene = make_scene("office")
    frames = sim.simulate_frames(scene=scene, trajectory="robot", n_frames=2, noise="kinect", camera="kinect",
                                 seed=1, width=320, height=240)
    checked = 0
    for f in frames:
        gt, ids = visible_planes_with_ids(f, scene, noise="kinect")
        ps = extract_planes(f, ExtractionParams()).planes
        for r, pid in enumerate(ids):
            if (f.labels == pid).sum() < 3000:
                continue
            overlap = [((ps.labels == i) & (f.labels == pid)).sum() for i in range(len(ps))]
            assert overlap and max(overlap) > 0, f"plane {pid} not found"
            i = int(np.argmax(overlap))
            ang, off = plane_errors(np.r_[ps.normals[i], ps.offsets[i]], np.r_[gt.normals[r], gt.offsets[r]])
            # Tolerance from the noise model: 8 standard deviations of the least-squares fit the ground truth
            # predicts for these pixels under Kinect noise (plus a small floor).
            sd_ang = np.degrees(np.sqrt(np.trace(gt.covariances[r][:3, :3])))
            sd_off = np.sqrt(gt.covariances[r][3, 3])
            assert ang < 8 * sd_ang + 0.01 and off < 8 * sd_off + 0.001, (pid, ang, sd_ang, off, sd_off)
            checked += 1
    assert checked >= 4


def test_a_far_stereo_wall_is_not_dropped_as_a_bevel():
    """A far wall under stereo noise (office, 4.4 m: sigma about 5 cm, so its band is wide) whose points mostly lie
    where their pixel ray also meets a small fragment tilted across it. Such a plane is dropped as a bevel only when
    it is as narrow as a bevel (``bevel_max_width_voxels`` 3): the wall comes out whole and within a fraction of a
    degree; with no width limit (the default) it is dropped and a strip of it grows back tilted."""
    sim = pytest.importorskip("sim")
    from sim.ground_truth import planes_in_camera
    from sim.scenes import make_scene

    from reloc.evaluation.suite import EvalSpec, extraction_for_sensor
    from reloc.planes import plane_errors

    scene = make_scene("office")
    f = sim.simulate_frames(scene=scene, trajectory="random", n_frames=5, noise="stereo", camera="oak-d", seed=0)[4]
    h, w = f.depth_m.shape
    params = extraction_for_sensor(EvalSpec(noise="stereo", camera="oak-d", width=w, height=h))
    normals, offsets = planes_in_camera(scene, f.T_world_cam)
    row = scene.index_of(7)  # the far wall
    gt = np.r_[normals[row], offsets[row]]
    gt = -gt if gt[3] < 0 else gt  # normal toward the camera
    pixels = int((f.labels == 7).sum())
    assert pixels > 20000 and 4.0 < gt[3] < 5.0

    def best_match(p):
        ps = PlaneExtractor(p).extract(f).planes
        overlap = [int(((ps.labels == i) & (f.labels == 7)).sum()) for i in range(len(ps))]
        i = int(np.argmax(overlap))
        return overlap[i] / pixels, plane_errors(np.r_[ps.normals[i], ps.offsets[i]], gt)

    share, (ang, off) = best_match(params.with_(bevel_max_width_voxels=3.0))
    # Stereo noise at 4.4 m: 1 deg and 2 cm are several sigmas of a fit over 20,000+ pixels.
    assert share > 0.9 and ang < 1.0 and off < 0.02, (share, ang, off)
    assert params.bevel_max_width_voxels is None  # the default: any width
    share_old, (ang_old, _) = best_match(params)
    assert share_old < 0.5 and ang_old > 2.0, (share_old, ang_old)


@pytest.mark.parametrize("noise_seed", [0, 1])
def test_layers_of_a_far_stereo_wall_become_one_plane(noise_seed):
    """A wall 5.6 m away facing the camera under stereo noise (apartment, robot trajectory 3, frame 320): the
    disparity steps (1/8 px, 12-13 cm of depth there) put its points on a few depth levels, and without the layer
    merge (``layer_min_shared`` 0) it comes out as two parallel planes through the same pixels, one 13-15 cm off.
    With it (0.5, the default for a stereo camera's noise law) it is one plane over all its pixels, within 1 deg and
    3 cm (the steps' mean)."""
    sim = pytest.importorskip("sim")
    from sim.ground_truth import planes_in_camera
    from sim.scenes import make_scene
    from sim.trajectories import make_trajectory

    from reloc.evaluation.suite import EvalSpec, extraction_for_sensor

    scene = make_scene("apartment")
    pose = make_trajectory("robot", scene, 400, 3)[320:321]
    f = sim.simulate_frames(scene=scene, trajectory=pose, noise="stereo", camera="oak-d", seed=noise_seed)[0]
    h, w = f.depth_m.shape
    params = extraction_for_sensor(EvalSpec(noise="stereo", camera="oak-d", width=w, height=h))
    normals, offsets = planes_in_camera(scene, f.T_world_cam)
    row = scene.index_of(30)
    gt = np.r_[normals[row], offsets[row]]
    gt = -gt if gt[3] < 0 else gt
    wall = f.labels == 30
    assert wall.sum() > 20000 and 5.0 < gt[3] < 6.0

    def covering(p):
        ps = PlaneExtractor(p).extract(f).planes
        share = [int(((ps.labels == i) & wall).sum()) / wall.sum() for i in range(len(ps))]
        return [(s, *plane_errors(np.r_[ps.normals[i], ps.offsets[i]], gt)) for i, s in enumerate(share) if s >= 0.2]

    assert params.noise_model == "stereo" and params.layer_min_shared is None and params.layer_share == 0.5
    layers = covering(params.with_(layer_min_shared=0.0))
    assert len(layers) == 2 and max(off for _, _, off in layers) > 0.1, layers
    (share, ang, off), = covering(params)
    assert share > 0.95 and ang < 1.0 and off < 0.03, (share, ang, off)
    assert covering(params.with_(layer_min_shared=0.5)) == [(share, ang, off)]


def test_layers_merge_with_a_pixel_stride_too():
    """With ``pixel_stride`` 2 a block of 2x2 image pixels holds one pixel used, so two layers never shared one and
    the layer merge never fired; blocks are 2 pixels used square now. Office, robot trajectory 1, frame 0, stereo:
    the wall 4.5 m ahead has a layer of 1,676 pixels 7 cm behind it, turned over 2 deg; merged, the wall is one
    plane within 0.2 deg and 5 mm, and the other planes are as they were."""
    sim = pytest.importorskip("sim")
    from sim.ground_truth import planes_in_camera
    from sim.scenes import make_scene
    from sim.trajectories import make_trajectory

    from reloc.evaluation.suite import EvalSpec, extraction_for_sensor

    scene = make_scene("office")
    pose = make_trajectory("robot", scene, 10, 1)[0:1]
    f = sim.simulate_frames(scene=scene, trajectory=pose, noise="stereo", camera="oak-d", seed=0)[0]
    h, w = f.depth_m.shape
    params = extraction_for_sensor(EvalSpec(noise="stereo", camera="oak-d", width=w, height=h)).with_(pixel_stride=2)
    normals, offsets = planes_in_camera(scene, f.T_world_cam)

    def surfaces(p):
        ps = PlaneExtractor(p).extract(f).planes
        out = []
        for i in range(len(ps)):
            ids = f.labels[(ps.labels == i) & (f.labels > 0)]
            row = scene.index_of(int(np.bincount(ids).argmax()))
            gt = np.r_[normals[row], offsets[row]]
            out.append((row, *plane_errors(np.r_[ps.normals[i], ps.offsets[i]], -gt if gt[3] < 0 else gt)))
        return out

    layered = surfaces(params.with_(layer_min_shared=0.0))
    rows = [r for r, _, _ in layered]
    wall = next(r for r in rows if rows.count(r) == 2)  # one surface twice: the wall and its layer
    assert len(set(rows)) == len(rows) - 1
    assert max(ang for r, ang, _ in layered if r == wall) > 2.0
    merged = surfaces(params)
    assert len(merged) == len(layered) - 1 and len({r for r, _, _ in merged}) == len(merged)
    (ang, off), = [(a, o) for r, a, o in merged if r == wall]
    assert ang < 0.2 and off < 0.005, (ang, off)
    assert [x for x in merged if x[0] != wall] == [x for x in layered if x[0] != wall]  # the others untouched


@pytest.mark.parametrize("noise_model, expected", [("stereo", 0.5), ("kinect", 0.0), ("tof", 0.0), ("constant", 0.0)])
def test_layers_are_merged_by_default_only_for_a_stereo_cameras_noise_law(noise_model, expected):
    assert ExtractionParams(noise_model=noise_model).layer_share == expected
    assert ExtractionParams(noise_model=noise_model, layer_min_shared=0.25).layer_share == 0.25
    assert ExtractionParams(noise_model=noise_model, layer_min_shared=0).layer_share == 0.0


@pytest.mark.parametrize("bad", [-0.1, 1.5, True, "half", float("nan")])
def test_a_bad_layer_share_is_named(bad):
    with pytest.raises(ValueError, match="layer_min_shared"):
        ExtractionParams(layer_min_shared=bad)


def test_noise_free_frame_fits_within_a_millimetre():
    depth, labels, planes = _box_room(noise_coeff=0.0, R=_rot([1.0, 0.2, 0.0], 0.3))
    ps = extract_planes(DepthFrame(depth, K, 0), ExtractionParams()).planes
    for k, (i, ang, off) in _matches(ps, labels, planes).items():
        assert ang < 0.01 and off < 0.001
        sel = ps.labels == i
        assert sel.sum() > 0.9 * (labels == k).sum()


def test_a_wall_across_many_voxels_is_one_plane_with_merging_and_several_without():
    depth, labels, planes = _box_room(R=_rot([0.0, 1.0, 0.0], 0.2))
    frame = DepthFrame(depth, K, 0)
    merged = extract_planes(frame, ExtractionParams()).planes
    split = extract_planes(frame, ExtractionParams(merge=False, min_plane_points=20, min_plane_area_m2=0.0)).planes
    for k in range(1, 7):
        wall = labels == k
        if wall.sum() < 0.05 * labels.size:
            continue
        # Extracted planes holding a real share (5 %) of the wall's pixels.
        holders = lambda ps: [i for i in range(len(ps)) if ((ps.labels == i) & wall).sum() > 0.05 * wall.sum()]
        assert len(holders(merged)) == 1, k
        assert len([i for i in range(len(split)) if ((split.labels == i) & wall).sum() > 100]) >= 5, k


def test_point_order_does_not_change_the_planes():
    depth, labels, planes = _box_room(R=_rot([0.2, 1.0, 0.0], 0.4))
    from reloc.extraction.backproject import depth_to_points

    pts, _ = depth_to_points(depth, K)
    pts = pts.copy()
    a = extract_planes_from_points(pts).planes
    perm = np.random.default_rng(0).permutation(len(pts))
    b = extract_planes_from_points(pts[perm]).planes
    assert len(a) == len(b) > 3
    # Sums in another order differ in the last bits; that may move a point sitting exactly on a band edge.
    assert np.abs(a.counts - b.counts).max() <= 1
    assert np.allclose(a.normals, b.normals, atol=1e-9) and np.allclose(a.offsets, b.offsets, atol=1e-9)
    assert np.allclose(a.radii, b.radii, atol=1e-6) and np.allclose(a.areas, b.areas)
    assert np.allclose(a.sample_points, b.sample_points, atol=1e-5)


def test_all_invalid_frame_gives_an_empty_set():
    depth = np.full((K.height, K.width), np.nan, np.float32)
    depth[::2] = 0.0
    depth[1::4] = -1.0
    depth[3::8] = np.inf
    res = extract_planes(DepthFrame(depth, K, 0), ExtractionParams())
    assert len(res.planes) == 0
    assert res.planes.labels.shape == depth.shape and np.all(res.planes.labels == -1)
    assert res.stats["points"] == 0
    assert len(extract_planes_from_points(np.zeros((0, 3))).planes) == 0


def test_invalid_depths_never_reach_a_fit():
    depth, labels, planes = _box_room(R=_rot([0.2, 1.0, 0.0], 0.4))
    clean = depth.copy()
    clean[::7, ::5] = 0.0
    dirty = depth.copy()
    bad = np.zeros(depth.shape, bool)
    bad[::7, ::5] = True
    values = np.array([np.nan, np.inf, -np.inf, -2.0, 0.0, 100.0], np.float32)
    dirty[bad] = values[np.arange(bad.sum()) % len(values)]
    a = extract_planes(DepthFrame(clean, K, 0), ExtractionParams()).planes
    b = extract_planes(DepthFrame(dirty, K, 0), ExtractionParams()).planes
    assert len(a) == len(b) > 3
    for name in ("normals", "offsets", "counts", "centroids", "radii", "areas", "covariances"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.all(np.isfinite(b.sample_points)) and np.all(b.labels[bad] == -1)


def test_ablation_switches_and_gravity_fallback():
    depth, labels, planes = _box_room(R=_rot([0.2, 1.0, 0.0], 0.4))
    frame = DepthFrame(depth, K, 0)
    base = extract_planes(frame, ExtractionParams())
    vr_ne = extract_planes(frame, ExtractionParams(adaptive_weights=False))
    assert len(vr_ne.planes) == len(base.planes)
    # Planes straight from the merged voxel moments (no refinement): the plane set assigns the points itself.
    unrefined = extract_planes(frame, ExtractionParams(refine_iterations=0)).planes
    assert len(unrefined) == len(base.planes)
    assert np.all(plane_angles(unrefined, base.planes) < 1.0)
    assert np.allclose(base.planes.gravity, [0.0, 1.0, 0.0])  # no gravity in the frame: the camera's +y
    assert extract_planes(frame, ExtractionParams(gravity_fallback="none")).planes.gravity is None
    # One extractor reused across frames gives the same planes as fresh calls (no state leaks between frames).
    ex = PlaneExtractor(ExtractionParams())
    other, _, _ = _box_room(seed=3)
    ex.extract(DepthFrame(other, K, 0))
    again = ex.extract(frame).planes
    assert np.array_equal(again.normals, base.planes.normals) and np.array_equal(again.labels, base.planes.labels)


def test_points_with_a_sensor_origin_and_bad_input():
    depth, labels, planes = _box_room(R=_rot([0.2, 1.0, 0.0], 0.4))
    from reloc.extraction.backproject import depth_to_points

    pts, _ = depth_to_points(depth, K)
    a = extract_planes_from_points(pts).planes
    shift = np.array([10.0, -3.0, 2.0])
    b = extract_planes_from_points(pts + shift, sensor_origin=shift, gravity=[0, 0, -1.0]).planes
    assert len(a) == len(b)
    # float32 points 10 m away carry ~1 um of rounding, which also changes the hashed subsample of the first
    # refinement pass; the planes agree to the noise level (a frame mix-up would be off by metres and degrees).
    assert np.allclose(a.normals, b.normals, atol=1e-3)
    assert np.allclose(b.offsets, np.einsum("ij,j->i", a.normals, -shift) + a.offsets, atol=1e-3 * 11)  # 11 m lever
    assert np.allclose(b.gravity, [0, 0, -1.0])
    with pytest.raises(ValueError, match="points_cam"):
        extract_planes_from_points(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="frame"):
        extract_planes(depth, ExtractionParams())


def test_gravity_sources_mounting_camera_y_with_its_tilt_tolerance_and_imu():
    """A camera pitched 25 degrees about its x axis in a box room: where each frame's gravity comes from, and the
    floor found as ground (matching's test, tolerance 15 deg) only when the gravity's own tolerance allows it."""
    from reloc.config import config_from_dict
    from reloc.matching.index import horizontal_facing

    R = _rot([1.0, 0.0, 0.0], np.radians(25.0))
    depth, labels, planes = _box_room(R=R)
    g_true = R @ np.array([0.0, 1.0, 0.0])  # the room's down (+y) seen from the pitched camera
    floor = int(np.argmax(planes[:, :3] @ -g_true))  # the plane whose normal points up
    frame = DepthFrame(depth, K, 0)

    def facing_of_floor(ps):
        i = _matches(ps, labels, planes)[floor + 1][0]
        return int(horizontal_facing(ps, np.radians(15.0))[i])

    # Mounting: the base is level and T_base_cam says how the camera sits on it (the default mounting, pitched).
    R_base_cam = np.array(config_from_dict({}).camera.T_base_cam).reshape(4, 4)[:3, :3] @ R.T
    T = np.eye(4)
    T[:3, :3] = R_base_cam
    cfg = config_from_dict({"camera": {"gravity_source": "mounting", "T_base_cam": T.ravel().tolist()}})
    p = ExtractionParams.from_config(cfg)
    assert p.gravity_fallback == "mounting"
    np.testing.assert_allclose(p.mounting_gravity_cam, g_true, atol=1e-12)
    ps = extract_planes(frame, p).planes
    np.testing.assert_allclose(ps.gravity, g_true, atol=1e-12)
    assert ps.gravity_tolerance_rad == 0.0 and facing_of_floor(ps) == 1
    # The camera's y axis is 25 deg off: the paper's tilt tolerance (camera.max_tilt_deg) widens the ground test.
    ps = extract_planes(frame, ExtractionParams.from_config(config_from_dict({}))).planes
    np.testing.assert_allclose(ps.gravity, [0.0, 1.0, 0.0])
    assert ps.gravity_tolerance_rad == pytest.approx(np.radians(20.0)) and facing_of_floor(ps) == 1
    level = ExtractionParams.from_config(config_from_dict({"camera": {"max_tilt_deg": 0.0}}))
    assert facing_of_floor(extract_planes(frame, level).planes) == 0
    # A frame with its own (IMU) gravity keeps it, measured; with gravity_source imu a frame without one has none.
    with_imu = DepthFrame(depth, K, 0, gravity_cam=g_true)
    ps = extract_planes(with_imu, ExtractionParams()).planes
    np.testing.assert_allclose(ps.gravity, g_true, atol=1e-12)
    assert ps.gravity_tolerance_rad == 0.0 and facing_of_floor(ps) == 1
    imu = ExtractionParams.from_config(config_from_dict({"camera": {"gravity_source": "imu"}}))
    assert extract_planes(frame, imu).planes.gravity is None
    with pytest.raises(ValueError, match="mounting_gravity_cam"):
        ExtractionParams(mounting_gravity_cam=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="camera_tilt_tolerance_rad"):
        ExtractionParams(camera_tilt_tolerance_rad=-0.1)


@pytest.mark.parametrize("distance_m", [
    pytest.param(2.0, marks=pytest.mark.xfail(
        strict=True, reason="known defect (docs/BENCHMARKS.md, 'A door in a niche'): a strip of 1,330 points tilted "
        "16 deg across the step's edge; a corner test at 10 deg drops it but costs relocalization; when this passes, "
        "drop the mark")),
    3.0,
])
def test_a_door_in_a_6cm_niche_stays_parallel_to_its_wall(distance_m):
    """The office's closed door sits 6 cm deep in the wall at y = 6 m (simulator, Kinect noise, 320x240). Seen
    square on, every extracted plane of that wall or door (a normal within 30 deg of the wall's) with 500 points or
    more is parallel to it within 1 deg: at 2 m Kinect noise is 6 mm, at 3 m 13 mm, and each plane holds thousands
    of points, so 1 deg is many sigmas. At 3 m the growth's 4 cm offset floor let the door and half the wall become
    one plane 3.5 deg off (the 2 cm floor keeps them apart); at 2 m a 16 deg strip of 1,330 points is left across
    the step's edge."""
    tilts = _tilts_at_the_door_niche(distance_m)
    assert len(tilts) >= 2  # the wall and the door (or what became of them)
    assert tilts.max() < 1.0, np.round(tilts, 2)


def test_a_corner_test_at_10_deg_drops_the_strip_across_the_niche():
    """``corner_min_angle_rad`` at 10 deg (20 by default): the strip across the niche's step at 2 m, tilted 16 deg
    to the wall and the door, is made of corner points and dropped as a bevel; wall and door stay within 1 deg."""
    tilts = _tilts_at_the_door_niche(2.0, corner_min_angle_rad=np.radians(10.0))
    assert len(tilts) >= 2
    assert tilts.max() < 1.0, np.round(tilts, 2)


def _tilts_at_the_door_niche(distance_m, **changes):
    """Angles (deg) to the wall at y = 6 m of the planes of 500 points or more facing it (normal within 30 deg), in
    a 320x240 Kinect frame of the office looking square on at the wall's door from ``distance_m``."""
    import sim
    from reloc.evaluation.suite import EvalSpec, extraction_for_sensor

    eye, target = np.array([-1.0, 6.0 - distance_m, 1.2]), np.array([-1.0, 6.0, 1.0])
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = eye
    frame = sim.simulate_frames("office", T[None], noise="kinect", camera="kinect", width=320, height=240, seed=0)[0]
    params = extraction_for_sensor(EvalSpec(noise="kinect", camera="kinect", width=320, height=240))
    ps = PlaneExtractor(params.with_(**changes)).extract(frame).planes
    normals_world = ps.normals @ T[:3, :3].T
    facing = (np.abs(normals_world[:, 1]) > np.cos(np.radians(30))) & (ps.counts >= 500)
    return np.degrees(np.arccos(np.clip(np.abs(normals_world[facing, 1]), 0.0, 1.0)))


def test_a_depth_limit_thousands_of_kilometres_deep_gives_the_same_planes():
    """``max_depth_m`` set far past any depth ("no limit"): the frustum's cell count (7e19 at 1,000 km and 25 cm
    voxels) wrapped round in int64, passed the dense-table guard, and the key pass wrote outside its table (a
    segmentation fault). The count is exact now, the frame's points are voxelized on their own, and the planes are
    those of the 8 m limit, since every depth here is under 5.4 m."""
    from reloc.extraction.backproject import depth_to_key_image
    from reloc.extraction.voxelize import MAX_FRUSTUM_CELLS, frustum_box, frustum_cells

    depth, _, _ = _box_room(R=_rot([0.2, 1.0, 0.1], 0.4))
    frame = DepthFrame(depth, K, 0)
    near = extract_planes(frame, ExtractionParams(voxel_size_m=0.25)).planes
    box = frustum_box(K, min_depth_m=0.3, max_depth_m=1e6, voxel_size_m=0.25)
    assert frustum_cells(box) == int(box[3]) * int(box[4]) * int(box[5]) > 7e19
    for max_depth in (1e6, 1e9):
        far = extract_planes(frame, ExtractionParams(voxel_size_m=0.25, max_depth_m=max_depth)).planes
        assert len(far) == len(near) == 4
        assert np.array_equal(far.counts, near.counts)
        assert np.allclose(far.normals, near.normals, atol=1e-9) and np.allclose(far.offsets, near.offsets, atol=1e-9)
    with pytest.raises(ValueError, match=f"box: {frustum_cells(box)} frustum cells, expected at most "
                                         f"{MAX_FRUSTUM_CELLS}"):
        depth_to_key_image(depth, K, box, voxel_size_m=0.25, max_depth_m=1e6)


def test_the_camera_y_gravity_of_a_frame_with_a_negative_fy_points_down():
    """ICL-NUIM's negative ``fy`` makes points with y up; the camera-y fallback gave +y (up) all the same, so the
    floor faced down and the ground constraint paired it with ceilings. Gravity is -y for such a frame."""
    from reloc.matching.index import horizontal_facing

    for fy in (262.5, -262.5):
        k = Intrinsics(fx=262.5, fy=fy, cx=159.5, cy=119.5, width=320, height=240)
        v, u = np.mgrid[0:k.height, 0:k.width]
        y_floor = 1.0 if fy > 0 else -1.0  # the floor 1 m below the camera, in the frame's own y convention
        with np.errstate(divide="ignore"):
            depth = np.where((v - k.cy) / k.fy * y_floor > 0.02, y_floor * k.fy / (v - k.cy), 0.0)
        depth = np.where(depth < 6.0, depth, 0.0).astype(np.float32)
        ps = extract_planes(DepthFrame(depth, k, 0)).planes
        assert np.allclose(ps.gravity, [0.0, y_floor, 0.0])
        floor = int(np.argmax(ps.areas))
        assert np.allclose(ps.normals[floor], [0.0, -y_floor, 0.0], atol=1e-3)
        assert horizontal_facing(ps, np.radians(15.0))[floor] == 1  # the floor faces up


def test_a_bevel_dropped_in_the_last_pass_gives_its_points_to_the_planes_around_it(monkeypatch):
    """The refinement's last pass (every point) drops a bevel across a corner; its points were left on no plane
    (label -1, out of the neighbours' counts) where the docstring says they go to the planes around it. Living room,
    hand-held walk, frame 3, Kinect noise: 356 such points. The plane set now assigns every point again then: its
    labels and counts are those of an assignment of every point to the final planes."""
    sim = pytest.importorskip("sim")
    from dataclasses import replace

    import reloc.extraction.merge as merge_mod
    import reloc.extraction.pipeline as pipeline_mod

    seen = {"dropped": False}
    keep = merge_mod.kfin.refine_keep

    def refine_keep(*args):
        nk = keep(*args)
        seen["dropped"] = bool(np.any(args[16] < 0))  # old_to_kept of this pass: -1 for a bevel
        return nk

    monkeypatch.setattr(merge_mod.kfin, "refine_keep", refine_keep)
    captured = {}
    assemble = pipeline_mod.assemble_plane_set

    def spy(grid, merged, **kw):
        captured.update(grid=grid, merged=merged, kw=kw)
        return assemble(grid, merged, **kw)

    monkeypatch.setattr(pipeline_mod, "assemble_plane_set", spy)
    f = sim.simulate_frames("living_room", "handheld", n_frames=10, noise="kinect", width=320, height=240, seed=3)[3]
    ps = extract_planes(f).planes
    assert seen["dropped"]  # the last pass of this frame dropped a bevel
    fresh = assemble(captured["grid"], replace(captured["merged"], point_plane=None, point_table=None, support=None),
                     **captured["kw"])
    np.testing.assert_array_equal(ps.labels, fresh.labels)
    np.testing.assert_array_equal(ps.counts, fresh.counts)
    assert int((ps.labels >= 0).sum()) == int(ps.counts.sum())
