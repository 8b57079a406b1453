"""The sequence reader on every real clip in ../shared/data/real: counts, intrinsics, poses, depth ranges, gravity."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.readers import open_sequence
from reloc.transforms import apply, transform_from_tum


def _tum_rows(path):
    """(stamps in seconds as float, 7 values) straight from a TUM text file, independently of the reader."""
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return np.array([float(r[0]) for r in rows]), np.array([[float(v) for v in r[1:]] for r in rows])


def _back_project(frame, rows, cols):
    k = frame.intrinsics
    v, u = np.mgrid[rows, cols]
    z = frame.depth_m[rows, cols].astype(np.float64)
    return np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], axis=-1).reshape(-1, 3)


def _fit_plane(points, viewpoint=np.zeros(3)):
    """Least-squares plane (n, d, rms) of (N, 3) points, the normal facing ``viewpoint``."""
    c = points.mean(axis=0)
    _, s, vt = np.linalg.svd(points - c, full_matrices=False)
    n = vt[2] if vt[2] @ (viewpoint - c) > 0 else -vt[2]
    return n, -float(n @ c), float(s[2] / np.sqrt(len(points)))


def test_tum_fr1_xyz_counts_intrinsics_stamps(real_data):
    seq = open_sequence(real_data / "tum_fr1_xyz")
    assert seq.format == "tum" and len(seq) == 37
    k = seq.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height, k.depth_scale) == (517.3, 516.5, 318.6, 255.3, 640, 480, 5000.0)
    # Exact nanoseconds from the decimal strings of depth.txt.
    assert seq.stamps_ns[0] == 1305031102_160407000
    assert seq.stamps_ns.dtype == np.int64 and np.all(np.diff(seq.stamps_ns) > 0)
    assert seq.rate_hz == pytest.approx(30.0, abs=1.0)
    assert seq.notes == ()


def test_tum_fr1_xyz_poses_are_nearest_groundtruth_rows(real_data):
    root = real_data / "tum_fr1_xyz"
    seq = open_sequence(root)
    gt_t, gt_v = _tum_rows(root / "groundtruth.txt")
    assert seq.pose_source == "groundtruth" and seq.has_pose.all()
    for frame in seq[::6]:
        i = int(np.argmin(np.abs(gt_t - frame.stamp_ns / 1e9)))
        assert abs(gt_t[i] - frame.stamp_ns / 1e9) < 0.005  # SOURCE.md: all within 5 ms
        np.testing.assert_allclose(frame.T_world_cam, transform_from_tum(gt_v[i]), atol=1e-12)
        assert frame.pose_source == "groundtruth"


def test_tum_fr1_xyz_association_tolerance(real_data):
    # SOURCE.md: every depth frame has a ground-truth row within 5 ms; at 1 ms some do not and are reported.
    assert open_sequence(real_data / "tum_fr1_xyz", max_dt_s=0.005).has_pose.all()
    tight = open_sequence(real_data / "tum_fr1_xyz", max_dt_s=0.001)
    unposed = int((~tight.has_pose).sum())
    assert 0 < unposed < 37
    assert f"{unposed} of 37 depth frames have no groundtruth row within 1 ms" in tight.notes[0]
    frame = tight[int(np.argmin(tight.has_pose))]
    assert frame.T_world_cam is None and frame.pose_source == "none"


def test_tum_fr1_xyz_gravity_agrees_with_mocap(real_data):
    """Accelerometer gravity (down, camera frame) against the mocap world's -z seen from the camera."""
    seq = open_sequence(real_data / "tum_fr1_xyz")
    assert seq.has_gravity.all()
    angles = []
    for frame in seq:
        down_from_gt = frame.T_world_cam[:3, :3].T @ np.array([0.0, 0.0, -1.0])
        g = frame.gravity_cam
        assert np.linalg.norm(g) == pytest.approx(1.0, abs=1e-9)
        angles.append(np.degrees(np.arccos(np.clip(g @ down_from_gt, -1, 1))))
    # The camera looks down at a desk: gravity has a large +y (down in the image) and +z (forward) part.
    assert seq[0].gravity_cam[1] > 0.6 and seq[0].gravity_cam[2] > 0.5
    assert np.max(angles) < 10.0 and np.mean(angles) < 6.0


def test_tum_fr1_xyz_depth(real_data):
    frame = open_sequence(real_data / "tum_fr1_xyz")[0]
    assert frame.depth_m.dtype == np.float32 and frame.depth_m.shape == (480, 640)
    valid = frame.valid_mask
    assert np.isnan(frame.depth_m[~valid]).all()  # 0 in the PNG becomes NaN
    assert 0.70 < valid.mean() < 0.80
    assert 0.4 < np.nanmin(frame.depth_m) and np.nanmax(frame.depth_m) < 5.0


def test_tum_fr2_desk_preassociated(real_data):
    root = real_data / "tum_fr2_desk"
    seq = open_sequence(root)
    assert len(seq) == 50 and seq.has_pose.all() and not seq.has_gravity.any()
    k = seq.intrinsics
    assert (k.fx, k.fy, k.cx, k.cy) == (520.9, 521.0, 325.1, 249.7)
    _, gt_v = _tum_rows(root / "groundtruth.txt")
    assert len(gt_v) == 50
    np.testing.assert_allclose(seq.T_world_cam, np.array([transform_from_tum(v) for v in gt_v]), atol=1e-12)
    # SOURCE.md: depth reaches about 10 m.
    far = max(float(np.nanmax(f.depth_m)) for f in seq[::10])
    assert 9.0 < far < 11.0


def test_icl_nuim_pose_folder_and_negative_fy(real_data):
    root = real_data / "icl_nuim_living_room"
    seq = open_sequence(root)
    assert seq.format == "pose_folder" and len(seq) == 5 and seq.synthetic_stamps
    assert seq.intrinsics.fy == -480.0 and seq.intrinsics.fx == 481.2
    rows = np.loadtxt(root / "pose.txt")
    for i, frame in enumerate(seq):
        np.testing.assert_allclose(frame.T_world_cam, transform_from_tum(rows[i]), atol=1e-12)
        assert frame.seq == i and frame.valid_mask.all()  # rendered: every pixel measured


def test_icl_nuim_wall_is_planar_and_consistent_across_frames(real_data):
    """A wall patch fits a plane to sub-millimetre RMS (noise-free), and the same wall seen from three frames lands
    on one world plane through the file poses with the negative fy: a wrong sign or pose convention puts it
    decimetres away. (ICL-NUIM's relative poses are good to about 1 degree / 1.5 cm: ICP on these frames converges
    to 0.3 mm residuals after corrections of that size.)"""
    seq = open_sequence(real_data / "icl_nuim_living_room")
    patches = {0: (slice(160, 200), slice(0, 40)), 1: (slice(200, 240), slice(160, 200)), 4: (slice(120, 160), slice(240, 280))}
    world = []
    for i, (rows, cols) in patches.items():
        frame = seq[i]
        pts = _back_project(frame, rows, cols)
        assert _fit_plane(pts)[2] < 0.001, f"frame {i}: wall patch RMS above 1 mm"
        n, d, _ = _fit_plane(apply(frame.T_world_cam, pts), viewpoint=frame.T_world_cam[:3, 3])
        world.append((n, d))
    n0, d0 = world[0]
    # The wall on the left of frame 0 is the plane x = -1.1 m of the world; its normal faces the room (+x).
    assert n0[0] > 0.99 and d0 == pytest.approx(1.1, abs=0.05)
    for n, d in world[1:]:
        assert np.degrees(np.arccos(min(1.0, n @ n0))) < 2.0
        assert d == pytest.approx(d0, abs=0.03)


def test_cape_single_frame_with_opencv_xml(real_data):
    root = real_data / "cape_single_frame"
    for path in (root, root / "depth_0.png"):
        seq = open_sequence(path)
        assert seq.format == "single_png" and len(seq) == 1 and not seq.has_pose.any()
        k = seq.intrinsics
        # IR_intrinsic_params of calib_params.xml (the depth camera), at the image size.
        assert k.fx == pytest.approx(575.92685448804468) and k.fy == pytest.approx(576.40791601093247)
        assert k.cx == pytest.approx(315.15026356388171) and k.cy == pytest.approx(230.58580662101753)
        assert (k.width, k.height, k.depth_scale) == (640, 480, 1000.0)
    frame = seq[0]
    # SOURCE.md: 0.83-6.99 m, 85 % valid.
    assert np.nanmin(frame.depth_m) == pytest.approx(0.832, abs=1e-6)
    assert np.nanmax(frame.depth_m) == pytest.approx(6.99, abs=1e-6)
    assert frame.valid_mask.mean() == pytest.approx(0.85, abs=0.01)
    assert frame.T_world_cam is None and frame.gravity_cam is None


def test_slicing_and_negative_index(real_data):
    seq = open_sequence(real_data / "tum_fr2_desk")
    sub = seq[10:20:3]
    assert len(sub) == 4 and list(sub.seqs) == [10, 13, 16, 19]
    np.testing.assert_array_equal(sub.stamps_ns, seq.stamps_ns[10:20:3])
    last = seq[-1]
    assert last.seq == 49 and last.stamp_ns == seq.stamps_ns[-1]
    np.testing.assert_array_equal(sub[1].depth_m, seq[13].depth_m)
    with pytest.raises(IndexError, match="index 50 out of range for a sequence of 50 frames"):
        seq[50]
