"""ROS bags: a tiny ROS 2 bag written with rosbags itself (depth 16UC1 or 32FC1, CameraInfo, odometry) reads back as
frames with the same depths, intrinsics, stamps and poses; a ROS 1 bag reads too."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="rosbags is the `ros` extra; the ROS bag source tests need it")

from rosbags.rosbag2 import Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from drivers.recorder import record  # noqa: E402
from drivers.readers import open_sequence  # noqa: E402
from drivers.rosbag import RosbagSource  # noqa: E402
from drivers.source import check_frame_contract, open_source  # noqa: E402
from reloc.transforms import exp_se3, quaternion_from_rotation  # noqa: E402

TS = get_typestore(Stores.ROS2_HUMBLE)
W, H = 8, 6
K = np.array([[50.0, 0.0, 3.5], [0.0, 51.0, 2.5], [0.0, 0.0, 1.0]])


def _header(stamp_ns, frame="cam"):
    Header, Time = TS.types["std_msgs/msg/Header"], TS.types["builtin_interfaces/msg/Time"]
    return Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=frame)


def _odometry(stamp_ns, T):
    t = TS.types
    q = quaternion_from_rotation(T[:3, :3])
    pose = t["geometry_msgs/msg/Pose"](position=t["geometry_msgs/msg/Point"](x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                                       orientation=t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
    twist = t["geometry_msgs/msg/Twist"](linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                         angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0))
    return t["nav_msgs/msg/Odometry"](
        header=_header(stamp_ns, "odom"), child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))


def make_bag(path, encoding="16UC1", n=4):
    rng = np.random.default_rng(0)
    depths = [rng.uniform(0.5, 5.0, size=(H, W)).astype(np.float32) for _ in range(n)]
    for d in depths:
        d[0, 0] = np.nan
    stamps = [1_700_000_000_000_000_000 + i * 33_333_333 for i in range(n)]
    poses = [exp_se3(rng.normal(size=6)) for _ in range(n)]
    Image, Info = TS.types["sensor_msgs/msg/Image"], TS.types["sensor_msgs/msg/CameraInfo"]
    roi = TS.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    with Writer(path, version=9) as writer:
        depth_c = writer.add_connection("/camera/depth/image_raw", Image.__msgtype__, typestore=TS)
        info_c = writer.add_connection("/camera/depth/camera_info", Info.__msgtype__, typestore=TS)
        odom_c = writer.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=TS)
        for i, (d, s, T) in enumerate(zip(depths, stamps, poses)):
            if encoding == "16UC1":
                raw = np.nan_to_num(np.rint(d * 1000), nan=0).astype("<u2")
            else:
                raw = d.astype("<f4")
            data = raw.tobytes()
            img = Image(header=_header(s), height=H, width=W, encoding=encoding, is_bigendian=0,
                        step=W * raw.itemsize, data=np.frombuffer(data, dtype=np.uint8))
            info = Info(header=_header(s), height=H, width=W, distortion_model="plumb_bob", d=np.zeros(5),
                        k=K.reshape(-1), r=np.eye(3).reshape(-1), p=np.zeros(12), binning_x=0, binning_y=0, roi=roi)
            writer.write(info_c, s, TS.serialize_cdr(info, Info.__msgtype__))
            writer.write(depth_c, s, TS.serialize_cdr(img, Image.__msgtype__))
            if i != 2:  # frame 2 has no odometry nearby
                writer.write(odom_c, s + 2_000_000, TS.serialize_cdr(_odometry(s + 2_000_000, T), "nav_msgs/msg/Odometry"))
    return depths, stamps, poses


@pytest.mark.parametrize("encoding,tol", [("16UC1", 0.0005), ("32FC1", 0.0)])
def test_bag_frames(tmp_path, encoding, tol):
    depths, stamps, poses = make_bag(tmp_path / "bag", encoding)
    with open_source(f"rosbag:{tmp_path / 'bag'}", rate="fast") as src:
        assert isinstance(src, RosbagSource) and len(src) == 4 and src.odom_topic == "/odom"
        k = src.intrinsics
        assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (50.0, 51.0, 3.5, 2.5, W, H)
        frames = list(src)
    check_frame_contract(frames, k)
    assert [f.stamp_ns for f in frames] == stamps
    for i, f in enumerate(frames):
        np.testing.assert_allclose(f.depth_m, depths[i], atol=tol + 1e-7)
        assert np.isnan(f.depth_m[0, 0])
        if i == 2:
            assert f.T_world_cam is None and f.pose_source == "none"
        else:
            np.testing.assert_allclose(f.T_world_cam, poses[i], atol=1e-9)
            assert f.pose_source == "odometry"


def test_bag_with_mounting_records_to_tum(tmp_path):
    _, _, poses = make_bag(tmp_path / "bag")
    T_base_cam = exp_se3(np.array([0.1, 0.0, 0.5, 0.0, 0.3, 0.0]))
    with RosbagSource(tmp_path / "bag", rate="fast", T_base_cam=T_base_cam) as src:
        record(src, tmp_path / "tum")
    seq = open_sequence(tmp_path / "tum")
    assert seq.pose_source == "odometry" and seq.has_pose.tolist() == [True, True, False, True]
    np.testing.assert_allclose(seq[1].T_world_cam, poses[1] @ T_base_cam, atol=1e-8)


def test_a_float_depth_bag_records_millimetres_not_whole_metres(tmp_path):
    """A 32FC1 bag's depth is in metres (scale 1 per metre); recorded into uint16 images at that scale every depth
    was rounded to whole metres. The recording is in millimetres: each depth read back within half of one."""
    depths, _, _ = make_bag(tmp_path / "bag", "32FC1")
    with RosbagSource(tmp_path / "bag", rate="fast") as src:
        assert src.intrinsics.depth_scale == 1.0
        record(src, tmp_path / "tum")
    seq = open_sequence(tmp_path / "tum")
    assert seq.intrinsics.depth_scale == 1000.0
    for i, d in enumerate(depths):
        got = seq[i].depth_m
        assert np.isnan(got[0, 0])
        np.testing.assert_allclose(got[1:, :], d[1:, :], atol=0.0005 + 1e-6)


def test_bag_errors(tmp_path):
    make_bag(tmp_path / "bag")
    with pytest.raises(ValueError, match=r"depth_topic: '/nope' is not a sensor_msgs/msg/Image topic"):
        RosbagSource(tmp_path / "bag", depth_topic="/nope")
    with pytest.raises(FileNotFoundError, match=r"missing: rosbag not found"):
        RosbagSource(tmp_path / "missing")


def test_a_ros1_bag_reads_its_camera_matrix_K(tmp_path):
    """ROS 1's CameraInfo spells the matrix ``K`` (ROS 2: ``k``); rosbags keeps the name, and every ROS 1 bag failed
    with AttributeError before its first frame."""
    from rosbags.rosbag1 import Writer as Writer1

    ts = get_typestore(Stores.ROS1_NOETIC)
    Image, Info = ts.types["sensor_msgs/msg/Image"], ts.types["sensor_msgs/msg/CameraInfo"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    path = tmp_path / "ros1.bag"
    stamps = [1_700_000_000_000_000_000 + i * 33_333_333 for i in range(3)]
    with Writer1(path) as w:
        ci = w.add_connection("/camera/depth/camera_info", Info.__msgtype__, typestore=ts)
        cd = w.add_connection("/camera/depth/image_raw", Image.__msgtype__, typestore=ts)
        for i, s in enumerate(stamps):
            hdr = Header(seq=i, stamp=Time(sec=s // 10**9, nanosec=s % 10**9), frame_id="cam")
            info = Info(header=hdr, height=H, width=W, distortion_model="plumb_bob", D=np.zeros(5), K=K.reshape(-1),
                        R=np.eye(3).reshape(-1), P=np.zeros(12), binning_x=0, binning_y=0, roi=roi)
            raw = np.full((H, W), 1500, "<u2")
            img = Image(header=hdr, height=H, width=W, encoding="16UC1", is_bigendian=0, step=W * 2,
                        data=np.frombuffer(raw.tobytes(), np.uint8))
            w.write(ci, s, ts.serialize_ros1(info, Info.__msgtype__))
            w.write(cd, s, ts.serialize_ros1(img, Image.__msgtype__))
    with RosbagSource(path, rate="fast") as src:
        k = src.intrinsics
        assert (k.fx, k.fy, k.cx, k.cy, k.width, k.height) == (50.0, 51.0, 3.5, 2.5, W, H)
        frames = list(src)
    assert [f.stamp_ns for f in frames] == stamps
    assert all(np.allclose(f.depth_m, 1.5) for f in frames)
