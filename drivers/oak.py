"""OAK stereo depth cameras through depthai 3 (``pip install 'voxelplane-reloc[oak]'``; depthai >= 3.6, < 4).

``depthai`` is imported only inside the functions of this module, so nothing else pays its import cost or needs it.

Pipeline: the left and right mono cameras (CAM_B, CAM_C) at ``width x height`` feed a ``StereoDepth`` node (preset,
subpixel, left-right check, extended disparity as configured) whose depth is aligned to ``align_to`` (the left
camera by default); the IMU accelerometer runs beside it when the device has one.

Conversions (each a small function, tested on host-built depthai messages without a device):

- depth: ``ImgFrame`` RAW16 millimetres -> metres float32, 0 -> NaN (:func:`depth_m_from_img_frame`);
- intrinsics: the frame's ``ImgTransformation`` at the output size, or the device calibration scaled to it
  (:func:`intrinsics_from_img_frame`);
- time: ``getTimestamp()`` (the device clock synced to the host's steady clock, a ``timedelta``) -> ``stamp_ns``
  (:func:`stamp_ns_from_timedelta`);
- gravity: accelerometer samples (specific force, pointing UP at rest, IMU frame, m/s^2) are low-passed
  (:class:`GravityFilter`) and rotated into the depth camera frame with the calibration's IMU-to-camera extrinsics:
  ``gravity_cam = -R_cam_imu @ a / |a|`` (:func:`gravity_cam_from_accel`).

Threads: a capture thread owns the device and the pipeline (always inside ``with`` blocks) and hands finished frames
to the consumer through a small queue (the oldest frame is dropped when the consumer falls behind, and counted);
``close()`` stops it and joins it before returning, so depthai never outlives its pipeline.

Errors: no device -> :class:`OakNotFoundError` within ``search_timeout_s``; a disconnect (X_LINK error, closed queue,
no frame for ``frame_timeout_s``) is reported and, with ``reconnect=True``, retried with the ``backoff_s`` waits;
otherwise it ends the iteration with :class:`OakDisconnectedError`.
"""

from __future__ import annotations

import datetime
import os
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Iterator, Sequence

import numpy as np

from reloc.camera import DepthFrame, Intrinsics

from drivers.source import FrameSource, SourceError, check_flag

__all__ = [
    "OakSource",
    "OakError",
    "OakNotFoundError",
    "OakDisconnectedError",
    "OakStats",
    "GravityFilter",
    "list_devices",
    "oak_kwargs_from_config",
    "stamp_ns_from_timedelta",
    "depth_m_from_img_frame",
    "intrinsics_from_img_frame",
    "intrinsics_from_calibration",
    "rotation_cam_imu",
    "stereo_noise_law",
    "gravity_cam_from_accel",
    "accel_samples",
    "frame_from_img_frame",
    "FrameAssembler",
    "pump",
    "PRESETS",
    "ALIGN_SOCKETS",
]

PRESETS = ("DEFAULT", "ROBOTICS", "ACCURACY", "DENSITY", "FAST_ACCURACY", "FAST_DENSITY", "HIGH_DETAIL", "FACE")
#: Depth alignment target -> depthai CameraBoardSocket name.
ALIGN_SOCKETS = {"left": "CAM_B", "right": "CAM_C", "rgb": "CAM_A"}
DEPTH_SCALE_MM = 1000.0


class OakError(SourceError):
    """Base class of the OAK driver's errors."""


class OakNotFoundError(OakError):
    """No (matching) device was found within the search timeout."""


class OakDisconnectedError(OakError):
    """The device stopped delivering frames (unplugged, X_LINK error) and reconnecting is off or gave up."""


# --------------------------------------------------------------------------------------------------- conversions


def stamp_ns_from_timedelta(td: datetime.timedelta) -> int:
    """Exact integer nanoseconds of a ``timedelta`` (depthai timestamps; microsecond resolution)."""
    return (td.days * 86_400 + td.seconds) * 1_000_000_000 + td.microseconds * 1_000


def depth_m_from_img_frame(img) -> np.ndarray:
    """(H, W) float32 metres from a depthai depth ``ImgFrame`` (RAW16, millimetres); 0 becomes NaN."""
    import depthai as dai

    if img.getType() != dai.ImgFrame.Type.RAW16:
        raise ValueError(f"img: expected a RAW16 depth frame (uint16 millimetres), got type {img.getType().name}")
    raw = np.asarray(img.getFrame())
    if raw.dtype != np.uint16 or raw.shape != (img.getHeight(), img.getWidth()):
        raise ValueError(f"img: expected uint16 ({img.getHeight()}, {img.getWidth()}), got {raw.dtype} {raw.shape}")
    depth = raw.astype(np.float32) * np.float32(1.0 / DEPTH_SCALE_MM)
    depth[raw == 0] = np.nan
    return depth


def intrinsics_from_calibration(calibration, socket, width: int, height: int) -> Intrinsics:
    """Intrinsics of camera ``socket`` from a ``CalibrationHandler``, scaled to ``width x height``."""
    K = np.asarray(calibration.getCameraIntrinsics(socket, int(width), int(height)), dtype=np.float64)
    return _intrinsics_from_K(K, width, height, f"calibration of {getattr(socket, 'name', socket)}")


def intrinsics_from_img_frame(img, calibration=None, socket=None) -> Intrinsics:
    """Intrinsics of a frame at its own (output) size: from its ``ImgTransformation`` when that is valid and of the
    frame's size, else from ``calibration`` for ``socket`` scaled to the frame. Raises ValueError when neither is
    usable."""
    width, height = int(img.getWidth()), int(img.getHeight())
    tr = img.getTransformation()
    if tr is not None and tr.isValid() and tuple(tr.getSize()) == (width, height):
        K = np.asarray(tr.getIntrinsicMatrix(), dtype=np.float64)
        if K.shape == (3, 3) and K[0, 0] > 0 and K[1, 1] > 0:
            return _intrinsics_from_K(K, width, height, "ImgTransformation")
    if calibration is None or socket is None:
        raise ValueError(f"img: no valid ImgTransformation for its {width}x{height} size and no calibration given")
    return intrinsics_from_calibration(calibration, socket, width, height)


def _intrinsics_from_K(K: np.ndarray, width: int, height: int, source: str) -> Intrinsics:
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"{source}: expected a finite 3x3 camera matrix, got {K.tolist()}")
    return Intrinsics(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
                      width=int(width), height=int(height), depth_scale=DEPTH_SCALE_MM)


#: Disparity noise (pixels, one sigma) with subpixel disparity: the simulator's OAK-D class model
#: (``sim.noise``, stereo); without subpixel, integer disparities: the quantization's 1 / sqrt(12).
SUBPIXEL_DISPARITY_SIGMA_PX = 0.08
INTEGER_DISPARITY_SIGMA_PX = 0.29


def stereo_noise_law(calibration, focal_px: float, subpixel: bool = True) -> tuple[str, float]:
    """``("stereo", c)`` with ``sigma_z = c z^2``, ``c = sigma_disparity / (f b)``: the depth noise the extraction
    should assume for a stereo pair of baseline ``b`` (``calibration.getBaselineDistance()``, centimetres) seen at
    focal length ``focal_px`` (pixels, the depth output's). Raises ValueError for a baseline or focal length that is
    not positive and finite."""
    baseline_m = float(calibration.getBaselineDistance()) / 100.0
    f = abs(float(focal_px))
    if not (np.isfinite(baseline_m) and baseline_m > 0):
        raise ValueError(f"calibration: stereo baseline {baseline_m * 100:g} cm, expected a positive distance")
    if not (np.isfinite(f) and f > 0):
        raise ValueError(f"focal_px: expected a positive focal length, got {focal_px!r}")
    sigma_px = SUBPIXEL_DISPARITY_SIGMA_PX if subpixel else INTEGER_DISPARITY_SIGMA_PX
    return "stereo", sigma_px / (f * baseline_m)


def device_calibration(device):
    """The calibration the device works with (``getCalibration``: what is flashed, with depthai's fallbacks merged
    in, such as the IMU extrinsics of boards whose EEPROM holds an identity); ``readCalibration`` (the EEPROM alone)
    only when that fails."""
    try:
        return device.getCalibration()
    except RuntimeError:
        return device.readCalibration()


def rotation_cam_imu(calibration, socket, rectification: np.ndarray | None = None) -> np.ndarray:
    """(3, 3) rotation taking IMU vectors into the depth camera frame: ``R_cam_imu`` from the calibration's
    IMU-to-camera extrinsics of ``socket``; for depth in a rectified frame, ``rectification`` (``R_rect_cam``) is
    applied on top."""
    T = np.asarray(calibration.getImuToCameraExtrinsics(socket), dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"calibration: IMU-to-camera extrinsics of {socket} should be 4x4, got {T.shape}")
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
        raise ValueError(f"calibration: IMU-to-camera rotation of {socket} is not orthonormal (is the IMU calibrated?)")
    if rectification is not None:
        R = np.asarray(rectification, dtype=np.float64) @ R
    return R


def gravity_cam_from_accel(accel_imu: np.ndarray, R_cam_imu: np.ndarray) -> np.ndarray:
    """Unit gravity (pointing down) in the camera frame from an accelerometer reading (specific force, IMU frame)."""
    a = np.asarray(accel_imu, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(a)
    if not np.isfinite(norm) or norm < 1e-6:
        raise ValueError(f"accel_imu: expected a non-zero finite acceleration, got {a.tolist()}")
    return -(np.asarray(R_cam_imu, dtype=np.float64) @ a) / norm


def accel_samples(imu_data) -> list[tuple[int, np.ndarray]]:
    """``(stamp_ns, [x, y, z])`` of every accelerometer report in a depthai ``IMUData`` message."""
    out = []
    for packet in imu_data.packets:
        acc = packet.acceleroMeter
        out.append((stamp_ns_from_timedelta(acc.getTimestamp()), np.array([acc.x, acc.y, acc.z], dtype=np.float64)))
    return out


class GravityFilter:
    """Low-pass of accelerometer samples (first order, time constant ``tau_s``), so that the robot's own
    accelerations average out of the gravity direction. ``update`` takes samples in stamp order; ``value`` is the
    filtered specific force (IMU frame) or None before the first sample."""

    def __init__(self, tau_s: float = 0.5) -> None:
        if not tau_s >= 0:
            raise ValueError(f"tau_s: expected >= 0 seconds, got {tau_s}")
        self.tau_s = float(tau_s)
        self.value: np.ndarray | None = None
        self._last_ns: int | None = None

    def update(self, stamp_ns: int, accel: np.ndarray) -> None:
        a = np.asarray(accel, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(a)):
            return
        if self.value is None or self.tau_s == 0:
            self.value = a.copy()
        else:
            dt = max(0.0, (stamp_ns - self._last_ns) / 1e9)
            alpha = 1.0 - np.exp(-dt / self.tau_s)
            self.value += alpha * (a - self.value)
        self._last_ns = int(stamp_ns)


def frame_from_img_frame(img, intrinsics: Intrinsics, *, seq: int, gravity_cam: np.ndarray | None = None) -> DepthFrame:
    """A :class:`DepthFrame` from a depthai depth ``ImgFrame`` (stamp from its host-synced timestamp)."""
    return DepthFrame(depth_m=depth_m_from_img_frame(img), intrinsics=intrinsics,
                      stamp_ns=stamp_ns_from_timedelta(img.getTimestamp()), seq=int(seq), gravity_cam=gravity_cam)


class FrameAssembler:
    """Turns depthai depth and IMU messages into :class:`DepthFrame` s.

    The intrinsics are fixed by the first frame (its ImgTransformation, else ``calibration`` of ``socket``) and
    later frames must match them; gravity is the low-passed accelerometer rotated by ``R_cam_imu`` (None: no
    gravity); ``seq`` counts every depth message, so a frame rejected here or dropped later leaves a gap; a stamp
    that does not increase is rejected. ``connect`` updates the calibration after a reconnect (seq and
    intrinsics carry on).
    """

    def __init__(self, *, calibration=None, socket=None, R_cam_imu: np.ndarray | None = None,
                 gravity_tau_s: float = 0.5) -> None:
        self.intrinsics: Intrinsics | None = None
        self.gravity_tau_s = gravity_tau_s
        self._seq = 0
        self._last_stamp: int | None = None
        self.connect(calibration=calibration, socket=socket, R_cam_imu=R_cam_imu)

    def connect(self, *, calibration=None, socket=None, R_cam_imu: np.ndarray | None = None) -> None:
        self.calibration, self.socket, self.R_cam_imu = calibration, socket, R_cam_imu
        self.gravity = GravityFilter(self.gravity_tau_s)

    def add_imu(self, imu_data) -> None:
        for stamp, a in accel_samples(imu_data):
            self.gravity.update(stamp, a)

    def frame(self, img) -> DepthFrame:
        """The next frame; raises ValueError (after counting it in ``seq``) for a frame that breaks the contract."""
        seq = self._seq
        self._seq += 1
        depth = depth_m_from_img_frame(img)
        intrinsics = intrinsics_from_img_frame(img, self.calibration, self.socket)
        if self.intrinsics is None:
            self.intrinsics = intrinsics
        elif intrinsics != self.intrinsics:
            raise ValueError(f"frame {seq}: intrinsics changed from {self.intrinsics} to {intrinsics}")
        g = None
        if self.R_cam_imu is not None and self.gravity.value is not None:
            g = gravity_cam_from_accel(self.gravity.value, self.R_cam_imu)
        stamp_ns = stamp_ns_from_timedelta(img.getTimestamp())
        frame = DepthFrame(depth_m=depth, intrinsics=self.intrinsics, stamp_ns=stamp_ns, seq=seq, gravity_cam=g)
        if self._last_stamp is not None and frame.stamp_ns <= self._last_stamp:
            raise ValueError(f"frame {seq}: stamp {frame.stamp_ns} ns does not increase (last {self._last_stamp})")
        self._last_stamp = frame.stamp_ns
        return frame


def pump(depth_q, imu_q, assembler: FrameAssembler, *, put, should_stop, stats: "OakStats",
         frame_timeout_s: float = 3.0, name: str = "oak") -> None:
    """Move messages from depthai queues into frames until ``should_stop()``: each frame goes to ``put(frame)``.

    A bad frame is counted in ``stats.bad_frames`` and skipped. Raises :class:`OakDisconnectedError` when no depth
    message arrives for ``frame_timeout_s``; depthai's queue-closed and X_LINK errors pass through to the caller,
    which decides on reconnecting.
    """
    timeout = datetime.timedelta(seconds=min(frame_timeout_s, 0.2))
    last_frame = time.monotonic()
    while not should_stop():
        msg = depth_q.get(timeout)
        if imu_q is not None:
            for imu_msg in imu_q.tryGetAll():
                assembler.add_imu(imu_msg)
        if msg is None:
            if time.monotonic() - last_frame > frame_timeout_s:
                raise OakDisconnectedError(f"{name}: no depth frame for {frame_timeout_s:g} s")
            continue
        last_frame = time.monotonic()
        try:
            frame = assembler.frame(msg)
        except ValueError as exc:
            stats.bad_frames += 1
            stats.last_error = str(exc)
            continue
        stats.frames += 1
        put(frame)


# --------------------------------------------------------------------------------------------------- devices


def _set_search_timeout(timeout_s: float) -> None:
    # depthai reads these when it searches for / connects to a device (milliseconds).
    os.environ["DEPTHAI_SEARCH_TIMEOUT"] = str(int(timeout_s * 1000))
    os.environ.setdefault("DEPTHAI_CONNECT_TIMEOUT", str(int(max(timeout_s, 2.0) * 1000)))


def _import_depthai():
    try:
        import depthai as dai
    except ImportError:
        raise OakError("the OAK driver needs depthai: pip install 'voxelplane-reloc[oak]' (depthai>=3.6,<4)") from None
    return dai


def list_devices(timeout_s: float = 2.0) -> list[dict]:
    """Attached OAK devices (id, name, state, platform, protocol), searching up to ``timeout_s``."""
    dai = _import_depthai()
    _set_search_timeout(timeout_s)
    deadline = time.monotonic() + timeout_s
    while True:
        found = dai.Device.getAllAvailableDevices()
        if found or time.monotonic() >= deadline:
            break
        time.sleep(0.2)
    return [{"id": d.getDeviceId(), "name": d.name, "state": d.state.name, "platform": d.platform.name,
             "protocol": d.protocol.name} for d in found]


def _find_device(dai, device_id: str | None, timeout_s: float):
    deadline = time.monotonic() + timeout_s
    while True:
        found = dai.Device.getAllAvailableDevices()
        for info in found:
            if device_id is None or device_id in (info.getDeviceId(), info.name):
                return info
        if time.monotonic() >= deadline:
            what = "no OAK device" if device_id is None else f"no OAK device {device_id!r}"
            seen = ", ".join(d.getDeviceId() for d in found) or "none"
            raise OakNotFoundError(
                f"{what} found within {timeout_s:g} s (devices seen: {seen}); check the cable and, on Linux, the "
                f"udev rule for Movidius devices; `reloc devices` lists what is attached"
            )
        time.sleep(0.2)


def _is_disconnect(exc: BaseException) -> bool:
    text = f"{type(exc).__name__}: {exc}"
    return any(key in text for key in ("X_LINK", "XLink", "QueueException", "was closed", "Communication exception"))


# --------------------------------------------------------------------------------------------------- source


@dataclass
class OakStats:
    """Counters of the capture thread (read them from the consumer; ints are updated atomically)."""

    frames: int = 0
    dropped: int = 0
    bad_frames: int = 0
    disconnects: int = 0
    reconnects: int = 0
    last_error: str = ""
    events: list[str] = field(default_factory=list)

    def event(self, text: str) -> None:
        self.events.append(f"{time.strftime('%H:%M:%S')} {text}")
        del self.events[:-50]


_END = object()


class OakSource(FrameSource):
    """Depth frames from an OAK camera. See the module docstring; parameters:

    - ``device_id``: device id or name (None: the first device found); ``search_timeout_s``: how long to look.
    - ``preset`` (one of ``PRESETS``), ``width``/``height`` (640x400), ``fps``, ``subpixel``, ``lr_check``,
      ``extended_disparity``, ``align_to`` ("left", "right" or "rgb").
    - ``imu``: use the accelerometer for gravity when the device has an IMU; ``imu_rate_hz``, ``gravity_tau_s``.
    - ``reconnect``: retry after a disconnect, waiting ``backoff_s`` in turn (the last value repeats);
      ``max_reconnects`` (None: forever). ``frame_timeout_s``: no frame for this long counts as a disconnect.
    - ``queue_frames``: frames buffered for the consumer (the oldest is dropped beyond it).

    The device is searched for when the source is made, so a missing camera fails at once with a clear message.
    """

    def __init__(self, device_id: str | None = None, *, preset: str = "DEFAULT", width: int = 640, height: int = 400,
                 fps: float = 30.0, subpixel: bool = True, lr_check: bool = True, extended_disparity: bool = False,
                 align_to: str = "left", imu: bool = True, imu_rate_hz: int = 100, gravity_tau_s: float = 0.5,
                 reconnect: bool = False, backoff_s: Sequence[float] = (0.5, 1.0, 2.0, 5.0),
                 max_reconnects: int | None = None, frame_timeout_s: float = 3.0, search_timeout_s: float = 2.0,
                 queue_frames: int = 4) -> None:
        super().__init__()
        preset = str(preset).upper()
        if preset not in PRESETS:
            raise ValueError(f"preset: expected one of {PRESETS}, got {preset!r}")
        if align_to not in ALIGN_SOCKETS:
            raise ValueError(f"align_to: expected one of {sorted(ALIGN_SOCKETS)}, got {align_to!r}")
        for name, v in (("width", width), ("height", height), ("queue_frames", queue_frames)):
            if not isinstance(v, int) or v <= 0:
                raise ValueError(f"{name}: expected a positive integer, got {v!r}")
        for name, v in (("fps", fps), ("frame_timeout_s", frame_timeout_s), ("search_timeout_s", search_timeout_s)):
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"{name}: expected a positive number, got {v!r}")
        backoff = tuple(float(b) for b in backoff_s)
        if not backoff or min(backoff) < 0:
            raise ValueError(f"backoff_s: expected a non-empty list of waits >= 0, got {list(backoff_s)}")
        if check_flag("subpixel", subpixel) and check_flag("extended_disparity", extended_disparity):
            raise ValueError("subpixel, extended_disparity: depthai 3.x cannot do both (its StereoDepth calls them "
                             "incompatible); expected one of them false")
        self.settings = dict(preset=preset, width=width, height=height, fps=float(fps),
                             subpixel=check_flag("subpixel", subpixel), lr_check=check_flag("lr_check", lr_check),
                             extended_disparity=check_flag("extended_disparity", extended_disparity),
                             align_to=align_to, imu=check_flag("imu", imu), imu_rate_hz=int(imu_rate_hz))
        self.gravity_tau_s = float(gravity_tau_s)
        self.reconnect = check_flag("reconnect", reconnect)
        self.backoff_s = backoff
        self.max_reconnects = max_reconnects
        self.frame_timeout_s = float(frame_timeout_s)
        self.search_timeout_s = float(search_timeout_s)
        self.stats = OakStats()
        self._queue: queue.Queue = queue.Queue(maxsize=queue_frames)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._intrinsics: Intrinsics | None = None
        self._calibration = None
        self._ready = threading.Event()
        self._assembler = FrameAssembler(gravity_tau_s=self.gravity_tau_s)

        self._device_info = self._locate(device_id)
        self.device_id = self._device_info.getDeviceId()
        self.name = f"oak:{self.device_id}"

    # The intrinsics are known once the first frame arrived (they depend on the device's calibration and the
    # output size); asking earlier starts the capture and waits for it.
    @property
    def intrinsics(self) -> Intrinsics:
        if self._intrinsics is None:
            self._start()
            if not self._ready.wait(self.search_timeout_s + self.frame_timeout_s + 10.0):
                raise OakError(f"{self.name}: no frame within {self.frame_timeout_s:g} s of starting the pipeline")
            if self._intrinsics is None:
                raise OakError(f"{self.name}: the pipeline stopped before the first frame ({self.stats.last_error})")
        return self._intrinsics

    @property
    def rate_hz(self) -> float:
        return self.settings["fps"]

    def noise_law(self) -> tuple[str, float] | None:
        """The stereo noise law from the device's baseline and the depth output's focal length (waits for the first
        frame, as :attr:`intrinsics` does); None when the calibration has no usable baseline."""
        fx = self.intrinsics.fx
        try:
            return stereo_noise_law(self._calibration, fx, self.settings["subpixel"])
        except (AttributeError, RuntimeError, ValueError) as exc:
            self.stats.event(f"noise law not known from the calibration ({exc}); the config's applies")
            return None

    def info(self) -> dict:
        return {**super().info(), "device_id": self.device_id, **self.settings}

    def _start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._capture_main, name=f"{self.name}-capture", daemon=True)
            self._thread.start()

    def _frames(self) -> Iterator[DepthFrame]:
        self._start()
        while True:
            item = self._queue.get()
            if item is _END:
                return
            if isinstance(item, BaseException):
                raise item
            yield item

    def _close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    # ----------------------------------------------------------------------------------------------- capture thread

    def _put(self, item) -> None:
        """Hand an item to the consumer; when the queue is full, drop the oldest frame (and count it)."""
        while True:
            try:
                self._queue.put_nowait(item)
                return
            except queue.Full:
                try:
                    old = self._queue.get_nowait()
                    if isinstance(old, DepthFrame):
                        self.stats.dropped += 1
                except queue.Empty:
                    pass

    def _capture_main(self) -> None:
        attempt = 0
        try:
            while not self._stop.is_set():
                frames_before = self.stats.frames
                try:
                    self._session()
                    if self._stop.is_set():
                        return
                    raise OakDisconnectedError(f"{self.name}: the pipeline stopped")
                except Exception as exc:  # noqa: BLE001 - every failure of the device is reported to the consumer
                    if self._stop.is_set():
                        return
                    self.stats.last_error = f"{type(exc).__name__}: {exc}"
                    disconnect = _is_disconnect(exc) or isinstance(exc, OakDisconnectedError)
                    if not disconnect:
                        self._put(exc if isinstance(exc, OakError) else OakError(f"{self.name}: {self.stats.last_error}"))
                        return
                    self.stats.disconnects += 1
                    self.stats.event(f"disconnected: {exc}")
                    if not self.reconnect:
                        self._put(exc if isinstance(exc, OakError) else
                                  OakDisconnectedError(f"{self.name}: disconnected ({exc})"))
                        return
                if self.stats.frames > frames_before:
                    attempt = 0  # the last connection worked: the backoff starts over
                # Wait, then look for the device again, until it is back or the attempts run out.
                while True:
                    if self.max_reconnects is not None and attempt >= self.max_reconnects:
                        self._put(OakDisconnectedError(
                            f"{self.name}: gave up after {attempt} reconnect attempts ({self.stats.last_error})"))
                        return
                    wait = self.backoff_s[min(attempt, len(self.backoff_s) - 1)]
                    attempt += 1
                    self.stats.event(f"reconnecting in {wait:g} s (attempt {attempt})")
                    if self._stop.wait(wait):
                        return
                    try:
                        self._device_info = self._locate(self.device_id)
                        break
                    except OakNotFoundError as nf:
                        self.stats.last_error = str(nf)
                        self.stats.event(str(nf))
                self.stats.reconnects += 1
        finally:
            self._ready.set()
            self._put(_END)

    def _locate(self, device_id: str | None):
        """DeviceInfo of the wanted device; raises OakNotFoundError after ``search_timeout_s``."""
        dai = _import_depthai()
        _set_search_timeout(self.search_timeout_s)
        return _find_device(dai, device_id, self.search_timeout_s)

    def _session(self) -> None:
        """One connection: device and pipeline inside ``with`` blocks, frames pumped until stop or failure."""
        dai = _import_depthai()
        with dai.Device(self._device_info) as device:
            with dai.Pipeline(device) as pipeline:
                self._run_pipeline(dai, device, pipeline)

    def _run_pipeline(self, dai, device, pipeline) -> None:
        s = self.settings
        socket = getattr(dai.CameraBoardSocket, ALIGN_SOCKETS[s["align_to"]])
        left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B)
        right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C)
        size = (s["width"], s["height"])
        stereo = pipeline.create(dai.node.StereoDepth).build(
            left.requestOutput(size, fps=s["fps"]), right.requestOutput(size, fps=s["fps"]),
            presetMode=getattr(dai.node.StereoDepth.PresetMode, s["preset"]))
        stereo.setLeftRightCheck(s["lr_check"])
        stereo.setSubpixel(s["subpixel"])
        stereo.setExtendedDisparity(s["extended_disparity"])
        stereo.setDepthAlign(socket)
        if s["align_to"] == "rgb":
            stereo.setOutputSize(s["width"], s["height"])
        depth_q = stereo.depth.createOutputQueue(maxSize=4, blocking=False)
        imu_q = None
        R_cam_imu = None
        calibration = device_calibration(device)
        self._calibration = calibration
        if s["imu"] and device.getConnectedIMU() not in ("NONE", ""):
            try:
                R_cam_imu = rotation_cam_imu(calibration, socket)
            except (RuntimeError, ValueError) as exc:
                self.stats.event(f"IMU not used: no IMU-to-camera extrinsics ({exc})")
            if R_cam_imu is not None:
                imu = pipeline.create(dai.node.IMU)
                # In the DepthAI IMU frame (the one the IMU-to-camera extrinsics start from), with the stored
                # affine calibration applied; RAW is the sensor's native frame in depthai 3.x firmware.
                imu.enableIMUSensor(dai.IMUSensor.ACCELEROMETER_CALIBRATED, s["imu_rate_hz"])
                imu.setBatchReportThreshold(5)
                imu.setMaxBatchReports(20)
                imu_q = imu.out.createOutputQueue(maxSize=50, blocking=False)
        pipeline.start()
        self.stats.event(f"streaming {s['width']}x{s['height']} depth aligned to {s['align_to']}"
                         + (" with IMU gravity" if imu_q is not None else ""))
        self._assembler.connect(calibration=calibration, socket=socket, R_cam_imu=R_cam_imu)
        pump(depth_q, imu_q, self._assembler, put=self._put_frame, stats=self.stats, name=self.name,
             should_stop=lambda: self._stop.is_set() or not pipeline.isRunning(), frame_timeout_s=self.frame_timeout_s)
        pipeline.stop()

    def _put_frame(self, frame: DepthFrame) -> None:
        if self._intrinsics is None:
            self._intrinsics = frame.intrinsics
            self._ready.set()
        self._put(frame)


def oak_kwargs_from_config(cfg) -> dict:
    """OakSource keywords from the config's ``oak`` section."""
    oak = cfg.oak
    return dict(preset=oak.preset, width=oak.width, height=oak.height, fps=oak.fps, subpixel=oak.subpixel,
                lr_check=oak.lr_check, extended_disparity=oak.extended_disparity, align_to=oak.align_to,
                imu=oak.imu, imu_rate_hz=oak.imu_rate_hz, gravity_tau_s=oak.gravity_tau_s, reconnect=oak.reconnect,
                backoff_s=tuple(oak.reconnect_backoff_s), frame_timeout_s=oak.frame_timeout_s,
                search_timeout_s=oak.search_timeout_s)
