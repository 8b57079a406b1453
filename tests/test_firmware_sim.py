"""The simulated firmware: its ground-truth path, its wheel odometry model, fault injection, endpoints, the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from firmware_bridge import HostBridge
from firmware_bridge.host import planar_transform
from firmware_bridge.mcu_sim import FaultInjector, OdometryModel, PlanarPath, SampledPath, open_endpoint
from reloc.transforms import invert, pose_error


def drive(model: OdometryModel, path: PlanarPath, seconds: float, rate_hz: float = 50.0):
    """Integrate ``model`` along ``path``; returns [(t, T_odom_base_est, T_odom_base_true, covariance)]."""
    T_map_odom = path.T_map_base(0.0)
    out = []
    prev = path.state(0.0)[:3]
    n = int(seconds * rate_hz)
    for k in range(1, n + 1):
        t = k / rate_hz
        now = path.state(t)[:3]
        model.step(prev, now, 1 / rate_hz)
        prev = now
        est = planar_transform(model.x, model.y, model.yaw)
        true = invert(T_map_odom) @ path.T_map_base(t)
        out.append((t, est, true, model.P.copy()))
    return out


def test_path_velocities_match_finite_differences():
    path = PlanarPath()
    for t in np.linspace(0, 40, 17):
        x, y, yaw, v, w = path.state(t)
        h = 1e-5
        x1, y1, yaw1, _, _ = path.state(t + h)
        x0, y0, yaw0, _, _ = path.state(t - h)
        assert v == pytest.approx(math.hypot(x1 - x0, y1 - y0) / (2 * h), rel=1e-6)
        assert w == pytest.approx(math.remainder(yaw1 - yaw0, 2 * math.pi) / (2 * h), abs=1e-6)
        # Heading along the velocity, always moving.
        assert abs(math.remainder(math.atan2(y1 - y0, x1 - x0) - yaw, 2 * math.pi)) < 1e-6 and v > 0.05


def test_perfect_odometry_reproduces_the_truth():
    for t, est, true, _ in drive(OdometryModel.perfect(), PlanarPath(), 40.0)[::100]:
        dt, dr = pose_error(est, true)
        assert dt < 1e-9 and dr < 1e-7, t


def test_default_odometry_drifts_and_its_covariance_grows():
    early, late = [], []
    for seed in range(4):
        run = drive(OdometryModel(seed=seed), PlanarPath(), 40.0)
        early.append(pose_error(run[249][1], run[249][2])[0])  # 5 s
        late.append(pose_error(run[-1][1], run[-1][2])[0])  # 40 s, one loop (about 11 m)
        yaw_var = [r[3][2, 2] for r in run]
        assert all(b >= a for a, b in zip(yaw_var, yaw_var[1:]))  # heading uncertainty only grows
        assert np.trace(run[-1][3]) > 10 * np.trace(run[249][3])
        assert np.all(np.linalg.eigvalsh(run[-1][3]) > 0)
    assert np.mean(late) > 3 * np.mean(early)
    assert 0.01 < np.mean(late) < 1.0  # realistic wheel odometry: centimetres to decimetres after 11 m


def test_sampled_path_follows_a_simulator_robot_trajectory():
    from reloc.config import Config
    from sim.scenes import make_scene
    from sim.trajectories import robot

    T_base_cam = np.asarray(Config().camera.T_base_cam).reshape(4, 4)
    T_world_cam = robot(make_scene("living_room"), 120, seed=0, rate_hz=30.0)
    path = SampledPath.from_T_world_cam(T_world_cam, 30.0, T_base_cam)
    for i in (0, 17, 60, 119):
        T_cam_est = path.T_map_base(i / 30.0) @ T_base_cam
        # Same camera position in the floor plane and same viewing heading (pitch and roll are not planar).
        assert np.allclose(T_cam_est[:2, 3], T_world_cam[i][:2, 3], atol=0.02)
        fwd_est, fwd_true = T_cam_est[:2, 2], T_world_cam[i][:2, 2]
        cos = fwd_est @ fwd_true / np.linalg.norm(fwd_est) / np.linalg.norm(fwd_true)
        assert cos > math.cos(math.radians(1.0))
    x, y, yaw, v, w = path.state(1000.0)  # after the end the base stands still
    assert (v, w) == (0.0, 0.0)
    # Perfect odometry along it reproduces it (turns on the spot included).
    for _, est, true, _ in drive(OdometryModel.perfect(), path, 4.0)[::20]:
        assert pose_error(est, true)[0] < 1e-9
    with pytest.raises(ValueError, match="T_world_cam"):
        SampledPath.from_T_world_cam(np.eye(4), 30.0, T_base_cam)
    with pytest.raises(ValueError, match="t_s"):
        SampledPath([0.0, 0.0], [0, 0], [0, 0], [0, 0])


def test_fault_injector_rates_match_their_settings():
    fi = FaultInjector(seed=0, bit_error_rate=1e-3, drop_rate=0.1, garbage_rate=0.05, unknown_rate=0.02)
    frame = bytes(range(1, 101))
    fates = [fi.apply(frame)[1] for _ in range(5000)]
    c = fi.counts
    assert c["dropped"] == fates.count("dropped") and c["corrupted"] == fates.count("corrupted")
    assert c["dropped"] / 5000 == pytest.approx(0.1, abs=0.015)
    kept = 5000 - c["dropped"]
    assert c["bits_flipped"] / (kept * 800) == pytest.approx(1e-3, rel=0.1)
    assert c["corrupted"] / kept == pytest.approx(1 - (1 - 1e-3) ** 800, abs=0.03)
    assert c["garbage_bursts"] / 5000 == pytest.approx(0.05, abs=0.01)
    assert c["unknown_frames"] / 5000 == pytest.approx(0.02, abs=0.006)
    out, fate = FaultInjector(seed=1).apply(frame)
    assert (out, fate) == (frame, "intact")
    with pytest.raises(ValueError, match="drop_rate"):
        FaultInjector(drop_rate=1.5)


def test_open_endpoint_specs(tmp_path):
    ep = open_endpoint(f"pty:{tmp_path / 'tty'}")
    try:
        assert ep.path == str(tmp_path / "tty") and (tmp_path / "tty").is_symlink()
    finally:
        ep.close()
    assert not (tmp_path / "tty").exists()
    srv = open_endpoint("tcp-listen:127.0.0.1:0")
    try:
        assert srv.path.startswith("socket://127.0.0.1:") and srv.port > 0
    finally:
        srv.close()
    with pytest.raises(ValueError, match="tcp-listen"):
        open_endpoint("tcp-listen:abc")
    with pytest.raises(ValueError, match="port"):
        open_endpoint("")


def test_cli_runs_the_simulator_against_a_host(tmp_path):
    from reloc.cli import cli

    link = tmp_path / "tty"
    out_json = tmp_path / "sim.json"
    bridge = HostBridge(str(link), reconnect_backoff_s=(0.02,), heartbeat_period_s=0.1)
    with bridge:
        result = CliRunner().invoke(
            cli, ["firmware-sim", "--port", f"pty:{link}", "--duration-s", "1.5", "--report-period-s", "0.5",
                  "--reloc-period-s", "0", "--json-out", str(out_json)],
        )
        host_stats = bridge.stats()
    assert result.exit_code == 0, result.output
    stats = json.loads(out_json.read_text())
    assert stats["odometry_sent"] > 20 and stats["host_heartbeats"] > 0 and stats["decoder"]["frames_bad"] == 0
    assert host_stats["odometry"] > 20 and host_stats["frames_bad"] == 0
