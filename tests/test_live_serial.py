"""The live loop with the firmware bridge, end to end over a pseudo-terminal: the simulated MCU drives the robot,
sends wheel odometry and asks for a relocalization; the camera renders the room from the MCU's true pose; the
loop builds submaps with the bridge's odometry, relocalizes, and the MCU checks the T_map_base it receives
against its ground truth. Also the `reloc run --serial` command against the simulated firmware."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
from click.testing import CliRunner
from helpers import wait_until

from drivers.source import FrameSource, Pacer
from firmware_bridge import HostBridge, PoseStatus
from firmware_bridge.mcu_sim import McuSimulator, PlanarPath, PtyEndpoint, SampledPath
from reloc.camera import DepthFrame
from reloc.config import Config
from reloc.live.factory import TruthPlanes, load_plane_map
from reloc.live.loop import THREAD_NAMES, LiveLoop
from reloc.live.params import LiveParams
from reloc.matching import Relocalizer
from sim.cameras import resolve_intrinsics
from sim.noise import make_noise
from sim.render import render
from sim.scenes import make_scene
from sim.trajectories import gravity_in_camera

T_BASE_CAM = np.array(Config().camera.T_base_cam).reshape(4, 4)
# A figure-eight through the living room along which single views relocalize most of the time.
PATH = PlanarPath(center_m=(3.0, 1.8), amplitude_m=(1.5, 1.0), period_s=30.0)




class RobotCamera(FrameSource):
    """A depth camera on the simulated robot: each frame is rendered from the MCU's true base pose at the moment it
    is taken (``T_world_cam = T_map_base @ T_base_cam``), stamped with the host clock, as a real camera would be."""

    def __init__(self, mcu: McuSimulator, scene, *, rate_hz: float = 30.0, width: int = 160, height: int = 100):
        super().__init__()
        self.mcu, self.scene = mcu, scene
        self._intr = resolve_intrinsics("oak-d", width, height)
        self.noise = make_noise("stereo")
        self.rate = rate_hz
        self.name = "robot-camera"

    @property
    def intrinsics(self):
        return self._intr

    def _frames(self):
        pacer = Pacer(self.rate)
        seq = 0
        while not self.closed:
            pacer.wait(0)
            now = time.monotonic_ns()
            T = self.mcu.true_T_map_base_at_host(now) @ T_BASE_CAM
            depth, labels = render(self.scene, self._intr, T)
            depth, labels = self.noise.apply(depth, labels, self._intr, np.random.default_rng(seq))
            yield DepthFrame(depth, self._intr, now, seq, T_world_cam=T, gravity_cam=gravity_in_camera(T),
                             pose_source="groundtruth", labels=labels)
            seq += 1


@pytest.fixture(scope="module")
def living_room():
    planes, plane_map = load_plane_map("sim:living_room")
    return make_scene("living_room"), planes, Relocalizer(plane_map)


def test_loop_relocalizes_end_to_end_with_the_simulated_firmware(tmp_path, living_room):
    scene, map_planes, reloc = living_room
    link = tmp_path / "ttyMCU"
    mcu = McuSimulator(PtyEndpoint(link), path=PATH, reloc_period_s=0.0, odom_rate_hz=50.0, seed=1,
                       pose_tolerance_m=0.1, pose_tolerance_deg=2.0)
    bridge = HostBridge(str(link), heartbeat_period_s=0.1, reconnect_backoff_s=(0.02,), pose_rate_hz=5.0)
    camera = RobotCamera(mcu, scene)
    params = LiveParams(window_frames=3, reloc_period_s=1000.0, T_base_cam=T_BASE_CAM, search_period_s=0.05)
    loop = LiveLoop(camera, TruthPlanes(scene), reloc, params=params, map_planes=map_planes, bridge=bridge)
    answered = []

    def firmware_side():
        try:
            assert wait_until(lambda: bridge.clock.synced and any(r.ok for r in loop.records()), 20.0)
            mcu.request_relocalization()
            answered.append(wait_until(lambda: any(c.request_id and c.status == PoseStatus.OK
                                                   for c in list(mcu.pose_checks)), 20.0))
            # Poses tracked from it with the odometry, a few seconds' worth.
            wait_until(lambda: sum(c.status == PoseStatus.TRACKED and c.stamped for c in list(mcu.pose_checks)) >= 15,
                       20.0)
        finally:
            loop.stop()

    with mcu, bridge:
        driver = threading.Thread(target=firmware_side)
        driver.start()
        summary = loop.run(duration_s=60.0)
        driver.join()
        mcu_stats = mcu.stats()
    camera.close()
    assert [t.name for t in threading.enumerate() if t.name in THREAD_NAMES] == []
    assert answered == [True], (summary.to_dict()["relocalizations"], mcu_stats)
    # Submaps were built with the firmware's odometry.
    assert summary.odometry["used"].get("bridge", 0) > 0
    # The MCU's request was served by a relocalization that carried its id...
    served = [r for r in summary.relocalizations if r.request_ids]
    assert served and "request" in served[0].trigger
    # ...and every relocalized T_map_base the MCU got matches its ground truth at the pose's stamp. A pose that left
    # before the clocks were synced (the start-up relocalization may) carries no MCU stamp and is judged at its
    # arrival, so the robot's motion meanwhile counts against it: those are held to the looser arrival-time bound.
    checks = [c for c in mcu.pose_checks if c.status == PoseStatus.OK and c.stamped]
    early = [c for c in mcu.pose_checks if c.status == PoseStatus.OK and not c.stamped]
    assert all(c.position_error_m < 0.3 for c in early), early
    assert checks and all(c.ok for c in checks), checks
    assert all(c.position_error_m < 0.1 and c.yaw_error_deg < 2.0 for c in checks)
    # Each relocalized pose came with its covariance (a spread of millimetres to a few centimetres)...
    assert all(0.0005 < c.position_sigma_m < 0.1 for c in checks + early), [c.position_sigma_m for c in checks]
    # ...and so did each pose tracked from it with the firmware's odometry: its spread grows with the odometry's
    # drift, and the truth lies within it.
    tracked = [c for c in mcu.pose_checks if c.status == PoseStatus.TRACKED and c.stamped]
    err = np.array([c.position_error_m for c in tracked])
    sigma = np.array([c.position_sigma_m for c in tracked])
    assert len(tracked) >= 10 and np.all(sigma > 0.0005) and sigma[-1] > sigma[0], sigma
    assert np.mean(err <= 3 * sigma) >= 0.95, np.c_[err, sigma]
    # The loop's own record agrees with the camera's truth.
    for r in summary.relocalizations:
        if r.ok:
            assert r.position_error_m < 0.1 and r.rotation_error_deg < 2.0
    assert summary.bridge["poses_sent"] >= len(checks) and summary.bridge["frames_bad"] == 0


def test_reloc_run_command_with_the_simulated_firmware_on_a_pty(tmp_path):
    """`reloc run --camera sim --serial PTY --follow-firmware` against the simulated firmware driving the robot
    trajectory (as `reloc firmware-sim --trajectory robot --scene living_room` does): the camera renders from the
    firmware's robot on the firmware's clock, so the firmware's own pose checks hold end to end."""
    from reloc.cli import cli
    from sim.trajectories import make_trajectory

    link = tmp_path / "ttyMCU"
    out = tmp_path / "summary.json"
    cfg = tmp_path / "live.yaml"
    # Submaps of 8 frames put together with the firmware's odometry: single views of this start are too narrow.
    # 150 frames give 5-7 relocalizations a run (60 gave 1-3, and in one CI run under load none).
    cfg.write_text("live:\n  status_period_s: 0.2\n  reloc_period_s: 0.5\nmapping:\n  submap_window_frames: 8\n")
    poses = make_trajectory("robot", make_scene("living_room", seed=0), 300, 0, rate_hz=30.0)
    # The whole pipeline runs here (extraction of noisy stereo frames, wheel odometry, fused submaps, a robot turning
    # on the spot at 60 deg/s), so poses are held to 0.2 m / 5 deg; the loop's own accuracy is held to 0.1 m / 2 deg
    # with exact planes in test_loop_relocalizes_end_to_end_with_the_simulated_firmware.
    tol_m, tol_deg = 0.2, 5.0
    mcu = McuSimulator(PtyEndpoint(link), path=SampledPath.from_T_world_cam(poses, 30.0, T_BASE_CAM),
                       reloc_period_s=0.5, seed=2, pose_tolerance_m=tol_m, pose_tolerance_deg=tol_deg)
    with mcu:
        result = CliRunner().invoke(cli, [
            "run", "--camera", "sim:living_room", "--map", "sim:living_room", "--serial", str(link),
            "--follow-firmware", "--firmware-frames", "300", "--frames", "150", "--summary", str(out),
            "--config", str(cfg), "--quiet"])
        assert result.exit_code == 0, result.output
        s = json.loads(out.read_text())
        # Let the last poses on the wire arrive before reading the firmware's side.
        assert wait_until(lambda: mcu.counters["poses_received"] >= s["bridge"]["poses_sent"], 10.0), mcu.stats()
        mcu_stats = mcu.stats()
        checks = list(mcu.pose_checks)
    assert s["frames"]["captured"] == 150 and s["source_events"]["end"] == "max_frames"
    assert s["relocalizations_ok"] >= 1
    for r in s["relocalizations"]:
        if r["status"] == "relocalized":
            assert r["position_error_m"] < tol_m and r["rotation_error_deg"] < tol_deg
    assert s["bridge"]["odometry"] > 0 and s["bridge"]["poses_sent"] >= 1 and s["bridge"]["frames_bad"] == 0
    assert s["odometry"]["used"].get("bridge", 0) > 0
    assert isinstance(s["odometry"]["frames_left_out"], int) and s["odometry"]["frames_left_out"] >= 0
    # The firmware checked every relocalized pose it got against its own ground truth.
    ok_checks = [c for c in checks if c.status == PoseStatus.OK]
    # Every relocalization reached it: none was held back behind the rate-limited TRACKED stream (CI once failed
    # here: the run's only successful relocalizations were periodic ones, dropped that way).
    assert len(ok_checks) >= s["relocalizations_ok"], (ok_checks, s["relocalizations_ok"], mcu_stats)
    assert ok_checks and all(c.ok for c in ok_checks), (ok_checks, mcu_stats)
    assert mcu_stats["decoder"]["frames_bad"] == 0
    assert "relocalizations:" in result.output


class SilentCamera(FrameSource):
    """A camera that never delivers a frame (blocked in its read until closed)."""

    name = "silent"

    @property
    def intrinsics(self):
        return resolve_intrinsics("oak-d", 160, 100)

    def _frames(self):
        while not self.closed:
            time.sleep(0.02)
        return
        yield


def test_a_request_without_camera_frames_is_answered_not_ready_and_a_blocked_source_is_closed(tmp_path, living_room):
    _, map_planes, reloc = living_room
    link = tmp_path / "ttyMCU"
    mcu = McuSimulator(PtyEndpoint(link), path=PATH, reloc_period_s=0.0, seed=3)
    bridge = HostBridge(str(link), heartbeat_period_s=0.1, reconnect_backoff_s=(0.02,))
    camera = SilentCamera()
    loop = LiveLoop(camera, lambda f: None, reloc, params=LiveParams(T_base_cam=T_BASE_CAM), map_planes=map_planes,
                    bridge=bridge)
    loop.capture_join_s = 0.2

    def firmware_side():
        try:
            assert wait_until(lambda: mcu.counters["host_heartbeats"] > 0, 10.0)
            mcu.request_relocalization()
            wait_until(lambda: mcu.counters["poses_received"] > 0, 10.0)
        finally:
            loop.stop()

    with mcu, bridge:
        driver = threading.Thread(target=firmware_side)
        driver.start()
        summary = loop.run(duration_s=30.0)
        driver.join()
    assert camera.closed  # the loop closed the blocked source to end its capture thread
    assert [t.name for t in threading.enumerate() if t.name in THREAD_NAMES] == []
    assert [c.status for c in mcu.pose_checks] == [PoseStatus.NOT_READY]
    assert summary.frames["captured"] == 0 and summary.relocalizations == []


def test_a_failing_link_is_counted_and_the_loop_goes_on(living_room):
    """Errors from the bridge (a driver bug, a dying USB adapter) are counted; frames and relocalizations go on."""
    scene, map_planes, reloc = living_room

    class FlakyBridge:
        def __init__(self):
            self.calls, self.poses = 0, []

        def get_event(self, timeout_s=0.0):
            self.calls += 1
            if self.calls % 3 == 0:
                raise OSError("[Errno 5] Input/output error")
            time.sleep(timeout_s)
            return None

        def T_odom_base_at(self, stamp_ns):
            return None

        def send_pose(self, T_map_base, stamp_ns, **kw):
            self.poses.append((T_map_base, kw))

        def send_status(self, *a, **kw):
            pass

        def stats(self):
            return {"calls": self.calls}

    from drivers.sim_source import SimSource

    src = SimSource("living_room", n_frames=30, camera="oak-d", width=160, height=100, rate=60.0)
    bridge = FlakyBridge()
    loop = LiveLoop(src, TruthPlanes(scene), reloc, params=LiveParams(queue_frames=100, T_base_cam=T_BASE_CAM),
                    map_planes=map_planes, bridge=bridge)
    summary = loop.run()
    assert summary.frames["processed"] == 30 and summary.errors == []
    assert summary.bridge["loop_serial_errors"] > 0 and summary.relocs_ok >= 1
    # The startup relocalization still reached the link as T_map_base = T_map_cam @ inv(T_base_cam).
    T_map_cam = next(r.T_map_cam for r in summary.relocalizations if r.ok)
    sent = [T for T, kw in bridge.poses if kw["status"] == PoseStatus.OK]
    assert sent and np.allclose(sent[0] @ T_BASE_CAM, T_map_cam)
