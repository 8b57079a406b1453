"""Sequence layouts built in tmp_path (TUM with labels/odometry/gravity, 7-Scenes, pose folder) and every error path."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from drivers.depth_png import write_depth_png, write_label_png
from drivers.readers import SEVEN_SCENES_INTRINSICS, gravity_from_kinect_accel, open_sequence, parse_stamp_ns
from reloc.transforms import exp_se3, tum_from_transform

W, H = 8, 6
CAMERA = {"fx": 10.0, "fy": 11.0, "cx": 3.5, "cy": 2.5, "width": W, "height": H, "depth_scale": 5000.0}


def _poses(n, seed=0):
    rng = np.random.default_rng(seed)
    return [exp_se3(rng.normal(scale=[0.5, 0.5, 0.5, 1.0, 1.0, 1.0])) for _ in range(n)]


def _depth(i):
    d = np.full((H, W), 1.0 + 0.1 * i, dtype=np.float32)
    d[0, 0] = np.nan
    return d


def _tum_line(stamp, T):
    return f"{stamp} " + " ".join(f"{v:.9f}" for v in tum_from_transform(T))


def make_tum(root, n=4, *, gt_offset_s=0.004, labels=False, extra=None):
    """A small TUM-layout sequence at 30 Hz with ground truth 4 ms off the depth stamps."""
    (root / "depth").mkdir(parents=True)
    (root / "camera.yaml").write_text(yaml.safe_dump(CAMERA))
    stamps = [f"{100 + i / 30:.6f}" for i in range(n)]
    poses = _poses(n)
    lines = ["# timestamp filename"]
    for i, s in enumerate(stamps):
        write_depth_png(root / "depth" / f"{s}.png", _depth(i), 5000.0)
        lines.append(f"{s} depth/{s}.png")
        if labels:
            write_label_png(root / "labels" / f"{s}.png", np.full((H, W), i + 1))
    (root / "depth.txt").write_text("\n".join(lines) + "\n")
    gt = [_tum_line(f"{float(s) + gt_offset_s:.6f}", T) for s, T in zip(stamps, poses)]
    (root / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(gt) + "\n")
    return stamps, poses


# --------------------------------------------------------------------------------------------------- TUM


def test_tum_layout_poses_labels_planes(tmp_path):
    stamps, poses = make_tum(tmp_path, labels=True)
    (tmp_path / "planes.json").write_text(json.dumps({"planes": [{"id": 1, "normal": [0, 0, 1], "offset": 0.0}]}))
    seq = open_sequence(tmp_path)
    assert seq.format == "tum" and len(seq) == 4 and seq.pose_source == "groundtruth"
    assert seq.scene_planes() == [{"id": 1, "normal": [0, 0, 1], "offset": 0.0}]
    for i, frame in enumerate(seq):
        assert frame.stamp_ns == parse_stamp_ns(stamps[i])
        np.testing.assert_allclose(frame.T_world_cam, poses[i], atol=1e-8)
        np.testing.assert_allclose(frame.depth_m[1:, 1:], 1.0 + 0.1 * i, atol=1 / 5000)
        assert np.isnan(frame.depth_m[0, 0])
        assert frame.labels.dtype == np.int32 and (frame.labels == i + 1).all()
        assert frame.intrinsics.fy == 11.0


def test_tum_frames_without_a_close_pose_are_kept_and_reported(tmp_path):
    make_tum(tmp_path, gt_offset_s=0.004)
    lines = (tmp_path / "groundtruth.txt").read_text().splitlines()
    # Drop the rows of frames 1 and 2: their nearest rows are then 29 ms away or more.
    (tmp_path / "groundtruth.txt").write_text("\n".join([lines[0], lines[1], lines[4]]) + "\n")
    seq = open_sequence(tmp_path, max_dt_s=0.02)
    assert seq.has_pose.tolist() == [True, False, False, True]
    assert seq.notes[0].startswith("2 of 4 depth frames have no groundtruth row within 20 ms")
    assert seq[1].T_world_cam is None and seq[0].T_world_cam is not None
    assert open_sequence(tmp_path, max_dt_s=0.1).has_pose.all()


def test_tum_odometry_and_gravity_files(tmp_path):
    stamps, poses = make_tum(tmp_path)
    odo = _poses(4, seed=7)
    (tmp_path / "odometry.txt").write_text("\n".join(_tum_line(s, T) for s, T in zip(stamps, odo)) + "\n")
    g = np.array([[0.0, 2.0, 0.0], [0.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 3.0]])
    (tmp_path / "gravity.txt").write_text("\n".join(f"{s} {x} {y} {z}" for s, (x, y, z) in zip(stamps, g)) + "\n")
    auto = open_sequence(tmp_path)
    assert auto.pose_source == "groundtruth"
    np.testing.assert_allclose(auto.gravity_cam, g / np.linalg.norm(g, axis=1, keepdims=True))
    odom = open_sequence(tmp_path, poses="odometry")
    assert odom.pose_source == "odometry" and odom[2].pose_source == "odometry"
    np.testing.assert_allclose(odom.T_world_cam, np.array(odo), atol=1e-8)
    (tmp_path / "groundtruth.txt").unlink()
    assert open_sequence(tmp_path).pose_source == "odometry"  # auto falls back to odometry
    assert open_sequence(tmp_path, poses="none").has_pose.sum() == 0
    with pytest.raises(FileNotFoundError, match=r"groundtruth.txt: groundtruth poses asked for but the file does not"):
        open_sequence(tmp_path, poses="groundtruth")


def test_kinect_accelerometer_axes():
    # At rest the accelerometer reads +9.81 along its "up" axis; a level Kinect (optical y down) reads +y.
    stamps = np.array([0, 10_000_000], dtype=np.int64)
    acc_t = np.arange(-50, 60, 2, dtype=np.int64) * 1_000_000
    level = np.tile([0.0, 9.81, 0.0], (len(acc_t), 1))
    np.testing.assert_allclose(gravity_from_kinect_accel(stamps, acc_t, level), [[0, 1, 0], [0, 1, 0]], atol=1e-12)
    # Pitched down by 30 degrees: gravity in the optical frame is (0, cos 30, sin 30); the sensor's z is backward.
    pitched = np.tile([0.0, 9.81 * np.cos(np.pi / 6), -9.81 * np.sin(np.pi / 6)], (len(acc_t), 1))
    out = gravity_from_kinect_accel(stamps, acc_t, pitched)
    np.testing.assert_allclose(out[0], [0, np.cos(np.pi / 6), np.sin(np.pi / 6)], atol=1e-12)
    far = gravity_from_kinect_accel(np.array([10**9], dtype=np.int64), acc_t, level, window_s=0.05)
    assert np.isnan(far).all()


def test_parse_stamp_ns_is_exact():
    assert parse_stamp_ns("1305031102.160407") == 1305031102160407000
    assert parse_stamp_ns("0.000000001") == 1
    assert parse_stamp_ns("12") == 12_000_000_000
    with pytest.raises(ValueError, match=r"depth.txt:3: expected a timestamp in seconds, got 'abc'"):
        parse_stamp_ns("abc", "depth.txt:3")


# --------------------------------------------------------------------------------------------------- 7-Scenes


def make_seven_scenes(root, n=3, size=(640, 480)):
    root.mkdir(parents=True, exist_ok=True)
    poses = _poses(n, seed=3)
    w, h = size
    for i in range(n):
        d = np.full((h, w), 1.5 + i * 0.25, dtype=np.float32)
        d[0, 0] = 0.0
        d[0, 1] = 65.535  # raw 65535: no measurement in 7-Scenes
        write_depth_png(root / f"frame-{i:06d}.depth.png", d, 1000.0)
        np.savetxt(root / f"frame-{i:06d}.pose.txt", poses[i], fmt="%.8e")
    return poses


def test_seven_scenes_default_intrinsics(tmp_path):
    poses = make_seven_scenes(tmp_path)
    seq = open_sequence(tmp_path)
    assert seq.format == "7scenes" and len(seq) == 3 and seq.intrinsics == SEVEN_SCENES_INTRINSICS
    assert "7-Scenes default intrinsics" in seq.notes[0] and seq.synthetic_stamps
    assert seq.rate_hz == pytest.approx(30.0)
    for i, frame in enumerate(seq):
        np.testing.assert_allclose(frame.T_world_cam, poses[i], atol=1e-7)
        assert np.isnan(frame.depth_m[0, 0]) and np.isnan(frame.depth_m[0, 1])
        assert frame.depth_m[5, 5] == pytest.approx(1.5 + i * 0.25, abs=1e-6)


def test_seven_scenes_intrinsics_files(tmp_path):
    make_seven_scenes(tmp_path, n=1, size=(W, H))
    (tmp_path / "camera-intrinsics.txt").write_text("500 0 3.5\n0 501 2.5\n0 0 1\n")
    k = open_sequence(tmp_path).intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height, k.depth_scale) == (500, 501, 3.5, 2.5, W, H, 1000.0)
    (tmp_path / "camera-intrinsics.txt").write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"camera-intrinsics.txt: expected a 3x3 camera matrix or 'fx fy cx cy', got 3"):
        open_sequence(tmp_path)
    (tmp_path / "camera-intrinsics.txt").unlink()
    with pytest.raises(ValueError, match=r"image is 8x6 and there is no camera.yaml or camera-intrinsics.txt"):
        open_sequence(tmp_path)
    (tmp_path / "camera.yaml").write_text(yaml.safe_dump({**CAMERA, "depth_scale": 1000.0}))
    assert open_sequence(tmp_path).intrinsics.fx == 10.0


def test_seven_scenes_pose_errors(tmp_path):
    make_seven_scenes(tmp_path, n=2, size=(640, 480))
    (tmp_path / "frame-000001.pose.txt").write_text("1 0 0 0\n0 2 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(ValueError, match=r"frame-000001.pose.txt: expected a rigid 4x4 transform"):
        open_sequence(tmp_path)
    (tmp_path / "frame-000001.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 nan\n0 0 0 1\n")
    with pytest.raises(ValueError, match=r"frame-000001.pose.txt:3: expected finite numbers, got '0 0 1 nan'"):
        open_sequence(tmp_path)
    (tmp_path / "frame-000001.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    with pytest.raises(ValueError, match=r"frame-000001.pose.txt: expected a 4x4 matrix \(4 lines of 4 numbers\), got 3"):
        open_sequence(tmp_path)
    (tmp_path / "frame-000001.pose.txt").unlink()
    with pytest.raises(FileNotFoundError, match=r"frame-000001.pose.txt: pose file missing for frame-000001.depth.png"):
        open_sequence(tmp_path)


# --------------------------------------------------------------------------------------------------- pose folder


def test_pose_folder_natural_order(tmp_path):
    (tmp_path / "depth").mkdir()
    (tmp_path / "camera.yaml").write_text(yaml.safe_dump({**CAMERA, "fy": -11.0}))
    poses = _poses(12, seed=5)
    for i in range(12):
        write_depth_png(tmp_path / "depth" / f"{i + 1}.png", _depth(i), 5000.0)
    rows = [" ".join(f"{v:.10f}" for v in tum_from_transform(T)) for T in poses]
    (tmp_path / "pose.txt").write_text("\n".join(rows) + "\n")
    seq = open_sequence(tmp_path)
    assert seq.format == "pose_folder" and len(seq) == 12 and seq.intrinsics.fy == -11.0
    assert [f.name for f in seq.depth_files][:3] == ["1.png", "2.png", "3.png"]
    assert seq.depth_files[9].name == "10.png"
    for i in (0, 9, 11):
        frame = seq[i]
        np.testing.assert_allclose(frame.depth_m[1:, 1:], 1.0 + 0.1 * i, atol=1 / 5000)
        np.testing.assert_allclose(frame.T_world_cam, poses[i], atol=1e-8)
    # One line short: the count mismatch is named.
    (tmp_path / "pose.txt").write_text("\n".join(rows[:-1]) + "\n")
    with pytest.raises(ValueError, match=r"pose.txt: 11 pose lines for 12 depth images"):
        open_sequence(tmp_path)
    rows[4] = "1 2 3 0 0 0"
    (tmp_path / "pose.txt").write_text("\n".join(rows) + "\n")
    with pytest.raises(ValueError, match=r"pose.txt:5: expected 7 numbers 'tx ty tz qx qy qz qw', got 6"):
        open_sequence(tmp_path)
    rows[4] = "1 2 3 0 0 0 0.5"
    (tmp_path / "pose.txt").write_text("\n".join(rows) + "\n")
    with pytest.raises(ValueError, match=r"pose.txt:5: expected a unit quaternion 'qx qy qz qw', got norm 0.5000"):
        open_sequence(tmp_path)


# --------------------------------------------------------------------------------------------------- errors


def test_missing_paths(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nowhere: sequence not found"):
        open_sequence(tmp_path / "nowhere")
    make_tum(tmp_path / "a")
    (tmp_path / "a" / "camera.yaml").unlink()
    with pytest.raises(FileNotFoundError, match=r"camera.yaml: camera intrinsics file not found"):
        open_sequence(tmp_path / "a")
    make_tum(tmp_path / "b")
    next((tmp_path / "b" / "depth").glob("*.png")).unlink()
    with pytest.raises(FileNotFoundError, match=r"100.000000.png: depth image listed at .*depth.txt:2 not found"):
        open_sequence(tmp_path / "b")
    (tmp_path / "c").mkdir()
    with pytest.raises(ValueError, match=r"c: unknown sequence layout; expected depth.txt \(TUM RGB-D\)"):
        open_sequence(tmp_path / "c")
    (tmp_path / "cloud.ply").write_bytes(b"ply\n")
    with pytest.raises(ValueError, match=r"a point cloud, not a depth sequence"):
        open_sequence(tmp_path / "cloud.ply")


def test_malformed_text_lines(tmp_path):
    make_tum(tmp_path)
    depth_txt = (tmp_path / "depth.txt").read_text().splitlines()
    (tmp_path / "depth.txt").write_text("\n".join(depth_txt + ["100.2 depth/x.png extra"]) + "\n")
    with pytest.raises(ValueError, match=r"depth.txt:6: expected 'timestamp filename', got '100.2 depth/x.png extra'"):
        open_sequence(tmp_path)
    (tmp_path / "depth.txt").write_text("\n".join([depth_txt[0], depth_txt[2], depth_txt[1]]) + "\n")
    with pytest.raises(ValueError, match=r"depth.txt:3: timestamps must increase, got 100.000000 after 100.033333"):
        open_sequence(tmp_path)
    (tmp_path / "depth.txt").write_text("\n".join(depth_txt) + "\n")
    gt = (tmp_path / "groundtruth.txt").read_text().splitlines()
    gt[2] = gt[2].rsplit(" ", 1)[0] + " x"
    (tmp_path / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    with pytest.raises(ValueError, match=r"groundtruth.txt:3: expected numbers, got"):
        open_sequence(tmp_path)
    gt[2] = "100.1 1 2 3"
    (tmp_path / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    with pytest.raises(ValueError, match=r"groundtruth.txt:3: expected 8 columns 'timestamp tx ty tz qx qy qz qw', got 4"):
        open_sequence(tmp_path)
    gt[2] = "inf 1 2 3 0 0 0 1"
    (tmp_path / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    with pytest.raises(ValueError, match=r"groundtruth.txt:3: expected a finite timestamp, got 'inf'"):
        open_sequence(tmp_path)


def test_bad_images(tmp_path):
    make_tum(tmp_path, labels=True)
    files = sorted((tmp_path / "depth").glob("*.png"))
    write_depth_png(files[1], np.ones((H + 1, W), dtype=np.float32), 5000.0)
    files[2].write_bytes(b"not a png at all")
    seq = open_sequence(tmp_path)  # images are read lazily, one per frame asked for
    with pytest.raises(ValueError, match=r"100.033333.png: image is 8x7, expected 8x6 \(width x height"):
        seq[1]
    with pytest.raises(ValueError, match=r"100.066667.png: not a readable PNG image"):
        seq[2]
    write_label_png(tmp_path / "labels" / files[0].name, np.ones((H, W + 2)))
    with pytest.raises(ValueError, match=r"labels/100.000000.png: image is 10x6, expected 8x6"):
        seq[0]
    (tmp_path / "labels" / files[3].name).unlink()
    with pytest.raises(FileNotFoundError, match=r"labels/100.100000.png: label image missing"):
        open_sequence(tmp_path)


def test_bad_camera_yaml(tmp_path):
    make_tum(tmp_path)
    (tmp_path / "camera.yaml").write_text("fx: 10\nfy: 11\n")
    with pytest.raises(ValueError, match=r"camera.yaml: missing keys \['cx', 'cy', 'width', 'height'\]"):
        open_sequence(tmp_path)
    (tmp_path / "camera.yaml").write_text("fx: [1\n")
    with pytest.raises(ValueError, match=r"camera.yaml: not valid YAML"):
        open_sequence(tmp_path)
    # No default scale: a TUM sequence read at 1000 per metre instead of its 5000 was 5 times too far, silently.
    (tmp_path / "camera.yaml").write_text(yaml.safe_dump({k: v for k, v in CAMERA.items() if k != "depth_scale"}))
    with pytest.raises(ValueError, match=r"camera.yaml: missing key depth_scale \(the depth images' integers per "
                                         r"metre: 5000 for TUM RGB-D"):
        open_sequence(tmp_path)


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match=r"max_dt_s: expected a positive number of seconds, got -1"):
        open_sequence(tmp_path, max_dt_s=-1)
    with pytest.raises(ValueError, match=r"poses: expected 'auto', 'groundtruth', 'odometry' or 'none', got 'gt'"):
        open_sequence(tmp_path, poses="gt")


def test_opencv_xml_errors(tmp_path):
    write_depth_png(tmp_path / "d.png", _depth(0), 1000.0)
    with pytest.raises(FileNotFoundError, match=r"d.png: no calibration beside it"):
        open_sequence(tmp_path / "d.png")
    (tmp_path / "calib.xml").write_text("<?xml version='1.0'?><opencv_storage><RGB_intrinsic_params/></opencv_storage>")
    with pytest.raises(ValueError, match=r"calib.xml: no <IR_intrinsic_params> matrix .*found \['RGB_intrinsic_params'\]"):
        open_sequence(tmp_path)
    (tmp_path / "calib.xml").write_text("<opencv_storage><IR_intrinsic_params><rows>3</rows><cols>3</cols>"
                                        "<data>1 0 2 0 1 3 0 0</data></IR_intrinsic_params></opencv_storage>")
    with pytest.raises(ValueError, match=r"calib.xml: <IR_intrinsic_params> expected 9 finite values of a 3x3 matrix"):
        open_sequence(tmp_path)
    (tmp_path / "calib.xml").write_text("<opencv_storage><IR_intrinsic_params><rows>3</rows><cols>3</cols>"
                                        "<data>100 0 3.5 0 101 2.5 0 0 1</data></IR_intrinsic_params></opencv_storage>")
    k = open_sequence(tmp_path).intrinsics
    assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height, k.depth_scale) == (100, 101, 3.5, 2.5, W, H, 1000.0)

