"""The OAK driver up to the device boundary: depthai builds frames, transformations, calibration and IMU packets on
the host, and a host-only pipeline with a threaded host node feeds real depthai queues. No device pipeline is ever
created here (one waits ~11 s for a device); tests that need a camera are marked ``oak`` and skip without one."""

from __future__ import annotations

import datetime
import time

import numpy as np
import pytest

dai = pytest.importorskip("depthai", reason="depthai is the `oak` extra; the OAK driver tests need it")

from drivers.oak import (  # noqa: E402
    FrameAssembler,
    GravityFilter,
    OakDisconnectedError,
    OakError,
    OakNotFoundError,
    OakSource,
    OakStats,
    accel_samples,
    depth_m_from_img_frame,
    gravity_cam_from_accel,
    intrinsics_from_img_frame,
    oak_kwargs_from_config,
    pump,
    rotation_cam_imu,
    stamp_ns_from_timedelta,
    stereo_noise_law,
)
from drivers.source import check_frame_contract  # noqa: E402
from reloc.transforms import rotation_from_axis_angle  # noqa: E402

K_FULL = [[800.0, 0.0, 639.5], [0.0, 801.0, 399.5], [0.0, 0.0, 1.0]]  # 1280x800 sensor


def depth_img(depth_mm: np.ndarray, *, stamp_s: float = 1.0, seq: int = 0, transformation=True) -> "dai.ImgFrame":
    h, w = depth_mm.shape
    img = dai.ImgFrame()
    img.setType(dai.ImgFrame.Type.RAW16)
    img.setWidth(w)
    img.setHeight(h)
    img.setFrame(np.ascontiguousarray(depth_mm, dtype=np.uint16))
    img.setSequenceNum(seq)
    img.setTimestamp(datetime.timedelta(seconds=stamp_s))
    if transformation:
        # The sensor's full-resolution calibration, scaled down to the output as the device does.
        tr = dai.ImgTransformation(2 * w, 2 * h, K_FULL)
        tr.addScale(0.5, 0.5)
        img.setTransformation(tr)
    return img


def imu_data(samples) -> "dai.IMUData":
    """IMUData of accelerometer reports ``(stamp_s, [x, y, z])``."""
    packets = []
    for stamp_s, xyz in samples:
        report = dai.IMUReportAccelerometer()
        report.x, report.y, report.z = (float(v) for v in xyz)
        ts = dai.Timestamp()
        ts.sec, ts.nsec = int(stamp_s), int(round((stamp_s % 1) * 1e9))
        report.timestamp = ts
        packet = dai.IMUPacket()
        packet.acceleroMeter = report
        packets.append(packet)
    data = dai.IMUData()
    data.packets = packets
    return data


def test_stamp_ns_from_timedelta():
    assert stamp_ns_from_timedelta(datetime.timedelta(seconds=12, microseconds=345678)) == 12_345_678_000
    assert stamp_ns_from_timedelta(datetime.timedelta(days=2, seconds=1)) == (2 * 86400 + 1) * 10**9


def test_depth_units_and_invalid_pixels():
    raw = np.array([[0, 1000, 2500], [65535, 1, 0]], dtype=np.uint16)
    d = depth_m_from_img_frame(depth_img(raw))
    assert d.dtype == np.float32 and d.shape == (2, 3)
    np.testing.assert_allclose(d[0, 1:], [1.0, 2.5])
    np.testing.assert_allclose(d[1, :2], [65.535, 0.001], rtol=1e-6)
    assert np.isnan(d[0, 0]) and np.isnan(d[1, 2])
    grey = dai.ImgFrame()
    grey.setType(dai.ImgFrame.Type.GRAY8)
    grey.setWidth(3)
    grey.setHeight(2)
    grey.setFrame(np.zeros((2, 3), np.uint8))
    with pytest.raises(ValueError, match=r"img: expected a RAW16 depth frame \(uint16 millimetres\), got type GRAY8"):
        depth_m_from_img_frame(grey)


def test_intrinsics_at_the_output_size():
    img = depth_img(np.zeros((400, 640), np.uint16))
    k = intrinsics_from_img_frame(img)
    # Full-resolution K scaled by 1/2 with the pixel-centre convention of depthai's scale.
    assert (k.width, k.height, k.depth_scale) == (640, 400, 1000.0)
    assert k.fx == pytest.approx(400.0) and k.fy == pytest.approx(400.5)
    assert k.cx == pytest.approx(319.75, abs=0.26) and k.cy == pytest.approx(199.75, abs=0.26)


def test_intrinsics_fall_back_to_calibration():
    calib = dai.CalibrationHandler()
    calib.setCameraIntrinsics(dai.CameraBoardSocket.CAM_B, K_FULL, 1280, 800)
    img = depth_img(np.zeros((400, 640), np.uint16), transformation=False)
    k = intrinsics_from_img_frame(img, calib, dai.CameraBoardSocket.CAM_B)
    assert (k.width, k.height) == (640, 400)
    assert k.fx == pytest.approx(400.0) and k.fy == pytest.approx(400.5)
    with pytest.raises(ValueError, match=r"img: no valid ImgTransformation for its 640x400 size and no calibration"):
        intrinsics_from_img_frame(img)


def test_stereo_noise_law_from_the_calibrations_baseline():
    calib = dai.CalibrationHandler()
    for socket in (dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C):
        calib.setCameraIntrinsics(socket, K_FULL, 1280, 800)
    # OAK-D: the right camera 7.5 cm from the left (depthai's units are centimetres).
    calib.setCameraExtrinsics(dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C, np.eye(3).tolist(),
                              [-7.5, 0.0, 0.0], [-7.5, 0.0, 0.0])
    model, c = stereo_noise_law(calib, 400.0)  # 640x400 output: f = 400 px
    # sigma_z = sigma_d z^2 / (f b): 0.08 px of subpixel disparity noise, 2.4 mm at 1 m, 2.2 cm at 3 m.
    assert model == "stereo" and c == pytest.approx(0.08 / (400.0 * 0.075))
    assert stereo_noise_law(calib, -400.0)[1] == pytest.approx(c)  # a mirrored focal length is still a focal length
    # Integer disparities: the quantization's 1 / sqrt(12) px.
    assert stereo_noise_law(calib, 400.0, subpixel=False)[1] == pytest.approx(0.29 / (400.0 * 0.075))
    with pytest.raises(ValueError, match="focal_px"):
        stereo_noise_law(calib, 0.0)

    class NoBaseline:  # what a calibration without stereo extrinsics would report, were it to answer at all
        def getBaselineDistance(self):
            return 0.0

    with pytest.raises(ValueError, match="stereo baseline 0 cm"):
        stereo_noise_law(NoBaseline(), 400.0)


def _imu_calibration(R_cam_imu):
    calib = dai.CalibrationHandler()
    calib.setCameraIntrinsics(dai.CameraBoardSocket.CAM_B, K_FULL, 1280, 800)
    calib.setImuExtrinsics(dai.CameraBoardSocket.CAM_B, np.asarray(R_cam_imu).tolist(), [1.0, 2.0, 3.0])
    return calib


def test_gravity_in_the_camera_frame_from_calibration_extrinsics():
    """A camera pitched 25 degrees down, its IMU mounted with axes permuted and flipped: the accelerometer reads the
    reaction to gravity (up) in IMU axes; the driver must return gravity (down) in optical axes."""
    R_cam_imu = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # det +1
    R_cam_imu = rotation_from_axis_angle([0.01, -0.02, 0.005]) @ R_cam_imu  # and a small mounting error
    calib = _imu_calibration(R_cam_imu)
    R = rotation_cam_imu(calib, dai.CameraBoardSocket.CAM_B)
    np.testing.assert_allclose(R, R_cam_imu, atol=1e-6)
    pitch = np.radians(25.0)
    gravity_cam = np.array([0.0, np.cos(pitch), np.sin(pitch)])  # down, seen by a camera pitched down
    accel_imu = R_cam_imu.T @ (-9.81 * gravity_cam)  # specific force: up, in IMU axes
    np.testing.assert_allclose(gravity_cam_from_accel(accel_imu, R), gravity_cam, atol=1e-6)
    with pytest.raises(ValueError, match=r"accel_imu: expected a non-zero finite acceleration"):
        gravity_cam_from_accel([0.0, 0.0, 0.0], R)


def test_accel_samples_and_gravity_filter():
    samples = accel_samples(imu_data([(5.25, [0.1, -9.8, 0.2]), (5.26, [0.0, -9.7, 0.0])]))
    assert [s for s, _ in samples] == [5_250_000_000, 5_260_000_000]
    np.testing.assert_allclose(samples[0][1], [0.1, -9.8, 0.2], rtol=1e-6)
    # A robot shaking at 5 Hz with +-3 m/s^2 sideways (up to 17 degrees off raw): a first-order low-pass of
    # tau = 0.5 s attenuates it by 1 / sqrt(1 + (2 pi f tau)^2) = 1 / 15.7, i.e. to about 1.1 degrees.
    f = GravityFilter(tau_s=0.5)
    for i in range(400):
        t = i * 0.01
        f.update(int(t * 1e9), [3.0 * np.sin(2 * np.pi * 5 * t), 9.81, 0.0])
    angle = np.degrees(np.arccos(f.value[1] / np.linalg.norm(f.value)))
    bound = np.degrees(np.arctan(3.0 / np.sqrt(1 + (2 * np.pi * 5 * 0.5) ** 2) / 9.81))
    assert angle <= 1.05 * bound and bound < 1.2
    with pytest.raises(ValueError, match=r"tau_s: expected >= 0 seconds"):
        GravityFilter(-1.0)


def test_assembler_frames_gravity_and_rejections():
    R_cam_imu = np.eye(3)
    asm = FrameAssembler(R_cam_imu=R_cam_imu, gravity_tau_s=0.0)
    raw = np.full((4, 6), 1500, np.uint16)
    f0 = asm.frame(depth_img(raw, stamp_s=1.0))
    assert f0.gravity_cam is None and f0.seq == 0 and f0.stamp_ns == 1_000_000_000
    asm.add_imu(imu_data([(1.01, [0.0, -9.81, 0.0])]))  # IMU y up -> camera y up -> gravity along -y
    f1 = asm.frame(depth_img(raw, stamp_s=1.033))
    np.testing.assert_allclose(f1.gravity_cam, [0.0, 1.0, 0.0])
    np.testing.assert_allclose(f1.depth_m, 1.5)
    with pytest.raises(ValueError, match=r"frame 2: stamp 1033000000 ns does not increase"):
        asm.frame(depth_img(raw, stamp_s=1.033))
    with pytest.raises(ValueError, match=r"frame 3: intrinsics changed"):
        asm.frame(depth_img(np.zeros((8, 12), np.uint16), stamp_s=1.1))
    f4 = asm.frame(depth_img(raw, stamp_s=1.2))
    assert f4.seq == 4  # the rejected frames leave a gap in seq
    check_frame_contract([f0, f1, f4], f0.intrinsics)


class FakeCamera(dai.node.ThreadedHostNode):
    """Host node standing in for the device: depth frames at 100 Hz, one of them broken, and IMU packets."""

    def __init__(self):
        super().__init__()
        self.depth = self.createOutput()
        self.imu = self.createOutput()

    def run(self):
        for i in range(6):
            if not self.isRunning():
                break
            t = 2.0 + 0.01 * i
            self.imu.send(imu_data([(t - 0.005, [0.0, 0.0, 9.81])]))  # IMU z up
            if i == 3:
                bad = dai.ImgFrame()
                bad.setType(dai.ImgFrame.Type.GRAY8)
                bad.setWidth(6)
                bad.setHeight(4)
                bad.setFrame(np.zeros((4, 6), np.uint8))
                bad.setTimestamp(datetime.timedelta(seconds=t))
                self.depth.send(bad)
            else:
                self.depth.send(depth_img(np.full((4, 6), 1000 + i, np.uint16), stamp_s=t, seq=i))
            time.sleep(0.01)


def test_pump_from_a_host_pipeline_through_real_queues():
    """Real depthai queues fed by a host-only pipeline (no device): frames come out converted, the broken frame is
    counted and skipped, gravity comes from the IMU queue, and a silent queue ends as a disconnect."""
    R_cam_imu = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # IMU z up = camera -y
    frames, stats = [], OakStats()
    asm = FrameAssembler(R_cam_imu=R_cam_imu, gravity_tau_s=0.0)
    with dai.Pipeline(False) as pipeline:
        cam = pipeline.create(FakeCamera)
        depth_q = cam.depth.createOutputQueue(maxSize=8, blocking=True)
        imu_q = cam.imu.createOutputQueue(maxSize=8, blocking=True)
        pipeline.start()
        with pytest.raises(OakDisconnectedError, match=r"test: no depth frame for 0.5 s"):
            pump(depth_q, imu_q, asm, put=frames.append, should_stop=lambda: False, stats=stats,
                 frame_timeout_s=0.5, name="test")
        pipeline.stop()
    assert stats.frames == 5 and stats.bad_frames == 1 and "RAW16" in stats.last_error
    assert [f.seq for f in frames] == [0, 1, 2, 4, 5]
    check_frame_contract(frames, frames[0].intrinsics)
    np.testing.assert_allclose([float(np.nanmean(f.depth_m)) for f in frames], [1.0, 1.001, 1.002, 1.004, 1.005])
    for f in frames:
        np.testing.assert_allclose(f.gravity_cam, [0.0, 1.0, 0.0], atol=1e-6)


def test_pump_stops_on_request_and_lets_queue_errors_through():
    asm = FrameAssembler()
    with dai.Pipeline(False) as pipeline:
        cam = pipeline.create(FakeCamera)
        depth_q = cam.depth.createOutputQueue(maxSize=8, blocking=True)
        pipeline.start()
        frames = []
        pump(depth_q, None, asm, put=frames.append, should_stop=lambda: len(frames) >= 2, stats=OakStats())
        assert len(frames) == 2
        depth_q.close()
        with pytest.raises(Exception, match=r"closed"):
            pump(depth_q, None, asm, put=frames.append, should_stop=lambda: False, stats=OakStats())
        pipeline.stop()


def test_config_keywords():
    from reloc.config import config_from_dict

    kw = oak_kwargs_from_config(config_from_dict({"oak": {"preset": "ROBOTICS", "width": 1280, "height": 800}}))
    assert kw["preset"] == "ROBOTICS" and (kw["width"], kw["height"]) == (1280, 800) and kw["search_timeout_s"] == 2.0


def _attached_devices():
    return dai.Device.getAllAvailableDevices()


@pytest.mark.oak
def test_live_camera_frames():
    """Needs an OAK camera: a few frames satisfy the contract at 640x400 with metric depth."""
    if not _attached_devices():
        pytest.skip("no OAK device attached")
    from drivers.source import open_source

    with open_source("oak", reconnect=False) as src:
        frames = []
        for f in src:
            frames.append(f)
            if len(frames) == 5:
                break
    check_frame_contract(frames, src.intrinsics)
    assert src.intrinsics.shape == (400, 640)
    assert 0.1 < float(np.nanmedian(frames[-1].depth_m)) < 20.0


# --------------------------------------------------------------------------------------------------- OakSource threads


class StampedCamera(dai.node.ThreadedHostNode):
    """Sends ``n`` depth frames with increasing stamps from ``t0`` (set before the pipeline starts), then idles."""

    def __init__(self):
        super().__init__()
        self.depth = self.createOutput()
        self.n, self.t0 = 0, 0.0

    def run(self):
        for i in range(self.n):
            if not self.isRunning():
                return
            self.depth.send(depth_img(np.full((4, 6), 2000, np.uint16), stamp_s=self.t0 + 0.01 * i, seq=i))
            time.sleep(0.002)
        while self.isRunning():
            time.sleep(0.01)


class FakeInfo:
    def getDeviceId(self):
        return "HOSTONLY"


class HostOak(OakSource):
    """OakSource whose device search and sessions are scripted: each session is a host-only pipeline sending
    ``frames`` frames, then ending as ``end``: "xlink" (the error depthai raises on an unplug), "silence" (no more
    frames: the frame timeout), "crash" (a non-device error) or "wait" (until closed)."""

    def __init__(self, sessions, missing_searches=0, **kw):
        self.sessions = list(sessions)
        self.missing_searches = missing_searches
        self.searches = 0
        self.t0 = 10.0
        super().__init__(**kw)

    def _locate(self, device_id):
        self.searches += 1
        if self.searches > 1 and self.missing_searches > 0:
            self.missing_searches -= 1
            raise OakNotFoundError("no OAK device 'HOSTONLY' found (scripted)")
        return FakeInfo()

    def _session(self):
        frames, end = self.sessions.pop(0)
        with dai.Pipeline(False) as pipeline:
            cam = pipeline.create(StampedCamera)
            cam.n, cam.t0 = frames, self.t0
            self.t0 += 1.0
            depth_q = cam.depth.createOutputQueue(maxSize=8, blocking=True)
            pipeline.start()
            self._assembler.connect()
            start = self.stats.frames
            try:
                pump(depth_q, None, self._assembler, put=self._put_frame, stats=self.stats, name=self.name,
                     frame_timeout_s=self.frame_timeout_s,
                     should_stop=lambda: self._stop.is_set() or (end != "silence" and end != "wait"
                                                                and self.stats.frames - start >= frames))
            finally:
                pipeline.stop()
        if end == "xlink":
            raise RuntimeError("Communication exception - possible device error. Original message 'Couldn't read "
                               "data from stream: 'depth' (X_LINK_ERROR)'")
        if end == "crash":
            raise ValueError("scripted failure")


class _Recorder:
    """A stand-in for a device-side node or the device: every call is recorded and returns this object, but for
    the calls given a value; ``self.out`` and ``self.depth`` are outputs with queues."""

    def __init__(self, log, name, values=None):
        self._log, self._name, self._values = log, name, values or {}

    def __getattr__(self, attr):
        if attr in ("out", "depth"):
            return _Recorder(self._log, f"{self._name}.{attr}")

        def call(*args, **kwargs):
            self._log.append((self._name, attr, args, kwargs))
            value = self._values.get(attr, self)
            return value() if callable(value) and attr in self._values else value
        return call


class _Queue:
    def get(self, timeout):
        return None

    def tryGetAll(self):
        return []


def test_the_pipeline_uses_the_devices_calibration_and_the_calibrated_accelerometer():
    """The wiring of a session, with the device and its pipeline replaced by recorders (no device is attached):
    the IMU extrinsics come from ``getCalibration`` (the EEPROM's ``readCalibration`` does not merge depthai's
    fallbacks: boards whose EEPROM holds an identity IMU rotation got gravity in the sensor's own axes), and the
    accelerometer stream is the calibrated one in the DepthAI IMU frame (RAW is the sensor's native frame)."""
    R_cam_imu = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    used, flashed = _imu_calibration(R_cam_imu), _imu_calibration(np.eye(3))
    log = []
    device = _Recorder(log, "device", {"getCalibration": lambda: used, "readCalibration": lambda: flashed,
                                       "getConnectedIMU": lambda: "BNO086"})
    queues = {"createOutputQueue": lambda: _Queue()}
    pipeline = _Recorder(log, "pipeline", {"isRunning": lambda: False,
                                           "create": lambda: _Recorder(log, "node", queues)})
    src = HostOak([], reconnect=False)
    src._run_pipeline(dai, device, pipeline)
    assert src._calibration is used and ("device", "readCalibration", (), {}) not in log
    np.testing.assert_allclose(src._assembler.R_cam_imu, R_cam_imu, atol=1e-6)
    sensors = [args[0] for name, attr, args, _ in log if attr == "enableIMUSensor"]
    assert sensors == [dai.IMUSensor.ACCELEROMETER_CALIBRATED]
    # A device whose working calibration cannot be read: the flashed one.
    device = _Recorder(log, "device", {"getCalibration": lambda: (_ for _ in ()).throw(RuntimeError("no")),
                                       "readCalibration": lambda: flashed, "getConnectedIMU": lambda: "NONE"})
    src._run_pipeline(dai, device, pipeline)
    assert src._calibration is flashed
    with pytest.raises(ValueError, match="subpixel, extended_disparity: depthai 3.x cannot do both"):
        HostOak([], subpixel=True, extended_disparity=True)


def test_source_reconnects_with_backoff_and_keeps_stamps_increasing():
    src = HostOak([(3, "xlink"), (4, "wait")], missing_searches=2, reconnect=True, backoff_s=(0.01, 0.02),
                  frame_timeout_s=1.0)
    frames = []
    with src:
        assert src.name == "oak:HOSTONLY"
        for f in src:
            frames.append(f)
            if len(frames) == 7:
                break
    assert not src._thread.is_alive()  # close() joined the capture thread
    check_frame_contract(frames, frames[0].intrinsics)
    assert [f.seq for f in frames] == list(range(7))
    assert src.stats.disconnects == 1 and src.stats.reconnects == 1 and src.searches == 4
    assert sum("reconnecting in" in e for e in src.stats.events) == 3  # two searches found nothing
    assert "X_LINK_ERROR" in src.stats.events[0]


def test_source_without_reconnect_reports_the_disconnect():
    src = HostOak([(2, "silence")], reconnect=False, frame_timeout_s=0.3)
    frames = []
    with pytest.raises(OakDisconnectedError, match=r"oak:HOSTONLY: no depth frame for 0.3 s"):
        for f in src:
            frames.append(f)
    src.close()
    assert len(frames) == 2 and src.intrinsics.shape == (4, 6)


def test_source_gives_up_after_max_reconnects_and_reports_other_errors():
    src = HostOak([(1, "xlink")], missing_searches=5, reconnect=True, backoff_s=(0.01,), max_reconnects=2)
    with pytest.raises(OakDisconnectedError, match=r"gave up after 2 reconnect attempts \(no OAK device 'HOSTONLY'"):
        list(src)
    src.close()
    src = HostOak([(1, "crash")], reconnect=True, backoff_s=(0.01,))
    with pytest.raises(OakError, match=r"oak:HOSTONLY: ValueError: scripted failure"):
        list(src)
    src.close()


def test_slow_consumer_drops_oldest_frames():
    src = HostOak([(12, "wait")], queue_frames=2, frame_timeout_s=2.0)
    it = iter(src)
    first = next(it)
    deadline = time.monotonic() + 5.0
    while src.stats.frames < 12 and time.monotonic() < deadline:
        time.sleep(0.01)
    rest = [next(it), next(it)]
    src.close()
    assert first.seq == 0 and src.stats.frames == 12
    # Only the newest frames were kept; the ones in between were dropped and counted.
    assert [f.seq for f in rest] == [10, 11] and src.stats.dropped == 9


def test_no_device_fails_fast_with_a_clear_message():
    if dai.Device.getAllAvailableDevices():
        pytest.skip("an OAK device is attached")
    with pytest.raises(OakNotFoundError, match=r"no OAK device found within 0.3 s \(devices seen: none\); check the"):
        OakSource(search_timeout_s=0.3)
