"""ROS 2 bags (and ROS 1 bags) as a frame source, through the pure-Python ``rosbags`` package (the ``ros`` extra).

Read from the bag:

- depth: ``sensor_msgs/msg/Image`` with encoding ``16UC1``/``mono16`` (millimetres, REP 118) or ``32FC1`` (metres);
  0 and NaN become NaN. ``stamp_ns`` is the message header stamp.
- intrinsics: the first ``sensor_msgs/msg/CameraInfo`` (``k``, ROS 1's ``K``, width, height) of the info topic.
- odometry (optional): ``nav_msgs/msg/Odometry``, the pose of ``child_frame_id`` in the odometry frame, associated
  with each depth stamp by the nearest message within ``max_dt_s``. With ``T_base_cam`` (the camera mounting in
  the child frame) the frame pose is ``T_odom_base @ T_base_cam``; without it the child frame is taken to be the
  camera's optical frame. Frames carry it with ``pose_source="odometry"``.

Topics are found by type when not named; a bag with several depth or info topics must name them.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np

from reloc.camera import DepthFrame, Intrinsics
from reloc.transforms import check_transform, rotation_from_quaternion, transform_from_rotation_translation

from drivers.source import FrameSource, Pacer, SourceError, parse_rate

__all__ = ["RosbagSource", "depth_from_image_msg"]

_IMAGE = "sensor_msgs/msg/Image"
_INFO = "sensor_msgs/msg/CameraInfo"
_ODOM = "nav_msgs/msg/Odometry"


def depth_from_image_msg(msg, where: str = "image") -> np.ndarray:
    """(H, W) float32 metres from a ``sensor_msgs/Image`` (16UC1/mono16 millimetres or 32FC1 metres)."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    enc = msg.encoding
    if enc in ("16UC1", "mono16"):
        dtype, scale = np.dtype(">u2" if msg.is_bigendian else "<u2"), 1e-3
    elif enc == "32FC1":
        dtype, scale = np.dtype(">f4" if msg.is_bigendian else "<f4"), 1.0
    else:
        raise ValueError(f"{where}: expected a depth image with encoding 16UC1, mono16 or 32FC1, got {enc!r}")
    if step < w * dtype.itemsize or data.size != h * step:
        raise ValueError(f"{where}: {data.size} bytes do not hold {h} rows of step {step} for width {w} ({enc})")
    rows = data.reshape(h, step)[:, : w * dtype.itemsize]
    values = np.ascontiguousarray(rows).view(dtype).reshape(h, w).astype(np.float32)
    depth = values * np.float32(scale)
    depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
    return depth


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


class RosbagSource(FrameSource):
    """Depth frames of a rosbag (see the module docstring). ``rate``: "recorded", "fast" or Hz."""

    def __init__(self, path: str | os.PathLike, *, depth_topic: str | None = None, info_topic: str | None = None,
                 odom_topic: str | None = None, T_base_cam: np.ndarray | None = None, max_dt_s: float = 0.02,
                 rate: "str | float" = "recorded", speed: float = 1.0) -> None:
        super().__init__()
        try:
            from rosbags.highlevel import AnyReader
        except ImportError:
            raise SourceError("reading rosbags needs the rosbags package: pip install 'voxelplane-reloc[ros]'") from None
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: rosbag not found")
        self.name = f"rosbag:{self.path}"
        self.rate = parse_rate(rate)
        self.speed = speed
        self.max_dt_ns = int(max_dt_s * 1e9)
        self.T_base_cam = None if T_base_cam is None else check_transform(T_base_cam, "T_base_cam")
        self._reader_cls = AnyReader
        with AnyReader([self.path]) as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            self.depth_topic = self._pick(topics, _IMAGE, depth_topic, "depth_topic", required=True)
            self.info_topic = self._pick(topics, _INFO, info_topic, "info_topic", required=True)
            self.odom_topic = self._pick(topics, _ODOM, odom_topic, "odom_topic", required=False)
            info = None
            for conn, _, raw in reader.messages([c for c in reader.connections if c.topic == self.info_topic]):
                info = reader.deserialize(raw, conn.msgtype)
                break
            if info is None:
                raise ValueError(f"{self.path}: no message on the camera info topic {self.info_topic}")
            K = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=np.float64).reshape(3, 3)  # ROS 1: K
            depth_conns = [c for c in reader.connections if c.topic == self.depth_topic]
            first = next(iter(reader.messages(depth_conns)), None)
            if first is None:
                raise ValueError(f"{self.path}: no message on the depth topic {self.depth_topic}")
            enc = reader.deserialize(first[2], first[0].msgtype).encoding
            self._intrinsics = Intrinsics(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
                                          width=int(info.width), height=int(info.height),
                                          depth_scale=1.0 if enc == "32FC1" else 1000.0)
            self._odom_stamps, self._odom_T = self._read_odometry(reader)
            self._count = sum(c.msgcount for c in depth_conns)

    def _pick(self, topics: dict, msgtype: str, wanted: str | None, arg: str, required: bool) -> str | None:
        if wanted is not None:
            if topics.get(wanted) != msgtype:
                raise ValueError(f"{arg}: {wanted!r} is not a {msgtype} topic of {self.path}; topics: {topics}")
            return wanted
        found = sorted(t for t, m in topics.items() if m == msgtype)
        if len(found) == 1:
            return found[0]
        if not found and not required:
            return None
        what = "no" if not found else f"{len(found)} ({', '.join(found)})"
        raise ValueError(f"{self.path}: {what} {msgtype} topics; name the one to use with {arg}; topics: {topics}")

    def _read_odometry(self, reader) -> tuple[np.ndarray, np.ndarray]:
        if self.odom_topic is None:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 4, 4))
        stamps, poses = [], []
        for conn, _, raw in reader.messages([c for c in reader.connections if c.topic == self.odom_topic]):
            msg = reader.deserialize(raw, conn.msgtype)
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            T = transform_from_rotation_translation(rotation_from_quaternion([q.x, q.y, q.z, q.w]), [p.x, p.y, p.z])
            if self.T_base_cam is not None:
                T = T @ self.T_base_cam
            stamps.append(_stamp_ns(msg.header))
            poses.append(T)
        order = np.argsort(np.array(stamps, dtype=np.int64), kind="stable")
        return np.array(stamps, dtype=np.int64)[order], np.array(poses).reshape(-1, 4, 4)[order]

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intrinsics

    @property
    def rate_hz(self) -> float | None:
        return self.rate if isinstance(self.rate, float) else None

    def __len__(self) -> int:
        return self._count

    def _pose_at(self, stamp_ns: int) -> np.ndarray | None:
        if len(self._odom_stamps) == 0:
            return None
        i = int(np.clip(np.searchsorted(self._odom_stamps, stamp_ns), 1, len(self._odom_stamps) - 1)) \
            if len(self._odom_stamps) > 1 else 0
        if i > 0 and abs(self._odom_stamps[i - 1] - stamp_ns) <= abs(self._odom_stamps[i] - stamp_ns):
            i -= 1
        return self._odom_T[i] if abs(self._odom_stamps[i] - stamp_ns) <= self.max_dt_ns else None

    def _frames(self) -> Iterator[DepthFrame]:
        pacer = Pacer(self.rate, speed=self.speed)
        last = None
        with self._reader_cls([self.path]) as reader:
            conns = [c for c in reader.connections if c.topic == self.depth_topic]
            for seq, (conn, _, raw) in enumerate(reader.messages(conns)):
                if self.closed:
                    return
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = _stamp_ns(msg.header)
                if last is not None and stamp <= last:
                    continue  # out of order or duplicated: the contract wants increasing stamps
                depth = depth_from_image_msg(msg, f"{self.path} {self.depth_topic} message {seq}")
                if depth.shape != self._intrinsics.shape:
                    raise ValueError(f"{self.path} {self.depth_topic} message {seq}: image {depth.shape[::-1]} "
                                     f"does not match the camera info {self._intrinsics.width}x{self._intrinsics.height}")
                T = self._pose_at(stamp)
                pacer.wait(stamp)
                last = stamp
                yield DepthFrame(depth_m=depth, intrinsics=self._intrinsics, stamp_ns=stamp, seq=seq, T_world_cam=T,
                                 pose_source="odometry" if T is not None else "none")

    def info(self) -> dict:
        return {**super().info(), "path": str(self.path), "depth_topic": self.depth_topic,
                "info_topic": self.info_topic, "odom_topic": self.odom_topic}
