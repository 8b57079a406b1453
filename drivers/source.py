"""The frame source interface: anything that yields depth frames.

A camera (``drivers.oak``), the simulator (``drivers.sim_source``) and file replay (``drivers.replay``) all
implement :class:`FrameSource`, so the live loop, the recorder and the tests know no difference:

    with open_source("replay:/data/fr1_xyz", rate="fast") as source:
        for frame in source:          # reloc.camera.DepthFrame
            ...

The contract, checked for every source by the tests (``check_frame_contract``):

- Iteration yields :class:`reloc.camera.DepthFrame` with ``depth_m`` float32 (H, W) in metres (NaN or 0 where there
  is no measurement) and ``intrinsics`` equal to :attr:`FrameSource.intrinsics` (the same for every frame).
- ``stamp_ns`` (int64 nanoseconds) strictly increases and ``seq`` increases (a gap in ``seq`` is a dropped frame).
- A frame may carry ``gravity_cam`` (unit, pointing down, camera frame: from an IMU or the simulator) and a pose
  ``T_world_cam`` whose ``pose_source`` says what it is ("odometry" from the robot or a tracker, "groundtruth" from
  a dataset or the simulator, :data:`reloc.camera.POSE_SOURCES`); the live loop uses only odometry-like poses to build submaps.
- :attr:`FrameSource.rate_hz` is the nominal frame rate, or None when unknown.
- ``close()`` releases the device or files and stops any capture thread (joined before it returns); it is
  idempotent, and leaving the ``with`` block calls it. Iterating a closed source raises ``RuntimeError``.

Pacing: a source that plays recorded or simulated frames either waits for each frame's time (``rate="recorded"``,
or a fixed rate in Hz) or yields as fast as the consumer takes them (``rate="fast"``); see :class:`Pacer`.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from typing import Callable, Iterator

import numpy as np

from reloc.camera import DepthFrame, Intrinsics

__all__ = ["FrameSource", "SourceError", "Pacer", "RATE_RANGE_HZ", "check_flag", "parse_rate", "check_frame_contract",
           "open_source", "SOURCE_SPECS"]

# Looked up when a Pacer is made, so tests can replace them.
_monotonic = time.monotonic
_sleep = time.sleep

SOURCE_SPECS = "sim[:SCENE], oak[:DEVICE_ID], replay:PATH (a sequence folder), rosbag:PATH"


class SourceError(RuntimeError):
    """A frame source failed in a way a person must act on (no device, device lost); the message says what."""


class FrameSource(ABC):
    """Base class of every source of depth frames (see the module docstring for the contract)."""

    #: Short description for logs and ``recording.json`` (``"replay:/data/x"``, ``"oak:1844301..."``).
    name: str = "source"

    def __init__(self) -> None:
        self._closed = False

    @property
    @abstractmethod
    def intrinsics(self) -> Intrinsics:
        """Intrinsics of every frame this source yields."""

    def noise_law(self) -> tuple[str, float] | None:
        """``(noise_model, noise_coeff)`` of this camera's depth noise as the extraction takes it (see
        :func:`reloc.extraction.params.noise_sigma`), or None when the source does not know it (the config's
        ``extraction.noise_model`` / ``noise_coeff`` then apply)."""
        return None

    @property
    def rate_hz(self) -> float | None:
        """Nominal frame rate, or None when unknown."""
        return None

    @abstractmethod
    def _frames(self) -> Iterator[DepthFrame]:
        """Yield frames; called by ``__iter__`` on an open source."""

    def _close(self) -> None:
        """Release resources (override); called once."""

    def __iter__(self) -> Iterator[DepthFrame]:
        if self._closed:
            raise RuntimeError(f"{self.name}: the source is closed")
        return self._frames()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._close()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> "FrameSource":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def info(self) -> dict:
        """JSON-able description (written next to recordings)."""
        return {"name": self.name, "intrinsics": self.intrinsics.as_dict(), "rate_hz": self.rate_hz}


def check_flag(name: str, value) -> bool:
    """``value`` if it is a yes/no (``-o loop=true`` reads as one), else ValueError naming ``name``: any text was
    taken for yes (``loop=fasle`` looped a replay forever)."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: expected true or false, got {value!r}")
    return bool(value)


#: Frame rates a source paces at, Hz: below, a frame's wait overflows the clock; above, ask for "fast".
RATE_RANGE_HZ = (1e-3, 1e5)


def parse_rate(rate: "str | float | None") -> "str | float":
    """``"recorded"``, ``"fast"`` or a positive number of Hz (also as a string such as ``"15"``)."""
    if rate is None:
        return "recorded"
    if isinstance(rate, str):
        if rate in ("recorded", "fast"):
            return rate
        try:
            rate = float(rate)
        except ValueError:
            raise ValueError(f"rate: expected 'recorded', 'fast' or a frame rate in Hz, got {rate!r}") from None
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (
            RATE_RANGE_HZ[0] <= rate <= RATE_RANGE_HZ[1]):
        raise ValueError(f"rate: expected 'recorded', 'fast' or a frame rate of {RATE_RANGE_HZ[0]:g} to "
                         f"{RATE_RANGE_HZ[1]:g} Hz, got {rate!r}")
    return float(rate)


class Pacer:
    """Releases frames on time: at their recorded stamps, at a fixed rate, or at once (``"fast"``).

    ``wait(stamp_ns)`` sleeps until the frame is due. The schedule starts at the first call; a consumer that falls
    behind is not made to catch up with a burst (the schedule moves on from the late frame), so a slow consumer
    sees the source's rate, not a backlog. ``speed`` scales recorded time (2.0 plays twice as fast). ``clock`` and
    ``sleep`` are injectable for tests.
    """

    def __init__(self, rate: "str | float" = "recorded", *, speed: float = 1.0,
                 clock: Callable[[], float] | None = None, sleep: Callable[[float], None] | None = None) -> None:
        self.rate = parse_rate(rate)
        if not (isinstance(speed, (int, float)) and speed > 0):
            raise ValueError(f"speed: expected a positive factor, got {speed!r}")
        self.speed = float(speed)
        self._clock = clock or _monotonic
        self._sleep = sleep or _sleep
        self._t0_wall: float | None = None
        self._t0_stamp = 0

    def wait(self, stamp_ns: int) -> None:
        if self.rate == "fast":
            return
        now = self._clock()
        if self._t0_wall is None:
            self._t0_wall, self._t0_stamp = now, int(stamp_ns)
            return
        if self.rate == "recorded":
            due = self._t0_wall + (int(stamp_ns) - self._t0_stamp) / 1e9 / self.speed
        else:
            due = self._t0_wall + 1.0 / self.rate
        if due > now:
            self._sleep(due - now)
            now = due
        if self.rate == "recorded":
            # Late frames shift the schedule instead of producing a burst afterwards.
            if now > due:
                self._t0_wall += now - due
        else:
            self._t0_wall = now


def check_frame_contract(frames: list[DepthFrame], intrinsics: Intrinsics) -> None:
    """Raise AssertionError naming the first frame that breaks the source contract (used by tests and `record`)."""
    prev_stamp = prev_seq = None
    for i, f in enumerate(frames):
        assert isinstance(f, DepthFrame), f"frame {i}: expected a DepthFrame, got {type(f).__name__}"
        assert f.depth_m.dtype == np.float32 and f.depth_m.shape == intrinsics.shape, (
            f"frame {i}: depth {f.depth_m.dtype} {f.depth_m.shape}, expected float32 {intrinsics.shape}")
        assert f.intrinsics == intrinsics, f"frame {i}: intrinsics {f.intrinsics} differ from the source's"
        if prev_stamp is not None:
            assert f.stamp_ns > prev_stamp, f"frame {i}: stamp_ns {f.stamp_ns} not after {prev_stamp}"
            assert f.seq > prev_seq, f"frame {i}: seq {f.seq} not after {prev_seq}"
        if f.gravity_cam is not None:
            assert abs(np.linalg.norm(f.gravity_cam) - 1.0) < 1e-6, f"frame {i}: gravity_cam not unit"
        if f.T_world_cam is not None:
            assert f.pose_source in ("odometry", "groundtruth"), (
                f"frame {i}: pose_source {f.pose_source!r} for a frame with a pose")
        prev_stamp, prev_seq = f.stamp_ns, f.seq


def open_source(spec: str, **kwargs) -> FrameSource:
    """A frame source from a spec string (see ``SOURCE_SPECS``); ``kwargs`` go to the source's constructor.

    - ``sim`` or ``sim:SCENE``: :class:`drivers.sim_source.SimSource` (scene, trajectory, noise, camera, n_frames,
      seed, rate, ...).
    - ``oak`` or ``oak:DEVICE_ID``: :class:`drivers.oak.OakSource` (preset, width, height, align_to, imu, ...).
    - ``replay:PATH``: :class:`drivers.replay.ReplaySource` (rate, speed, loop, max_dt_s, ...). A bare existing
      path is taken as ``replay:PATH``.
    - ``rosbag:PATH``: :class:`drivers.rosbag.RosbagSource` (depth_topic, info_topic, odom_topic, T_base_cam, rate).
    """
    import os

    if not isinstance(spec, str) or not spec:
        raise ValueError(f"spec: expected a source spec ({SOURCE_SPECS}), got {spec!r}")
    kind, _, arg = spec.partition(":")
    try:
        if kind == "sim":
            from drivers.sim_source import SimSource

            return SimSource(**({"scene": arg} if arg else {}), **kwargs)
        if kind == "oak":
            from drivers.oak import OakSource

            return OakSource(**({"device_id": arg} if arg else {}), **kwargs)
        if kind == "replay":
            from drivers.replay import ReplaySource

            if not arg:
                raise ValueError(f"spec: 'replay' needs a path, as in replay:PATH, got {spec!r}")
            return ReplaySource(arg, **kwargs)
        if kind == "rosbag":
            from drivers.rosbag import RosbagSource

            if not arg:
                raise ValueError(f"spec: 'rosbag' needs a path, as in rosbag:PATH, got {spec!r}")
            return RosbagSource(arg, **kwargs)
    except TypeError as exc:
        if "keyword argument" not in str(exc):
            raise
        raise ValueError(f"{spec}: {exc}") from None
    if os.path.exists(spec):
        return open_source(f"replay:{spec}", **kwargs)
    raise ValueError(f"spec: unknown frame source {spec!r}; expected {SOURCE_SPECS}")
