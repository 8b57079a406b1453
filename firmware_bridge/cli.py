"""``reloc firmware-sim``: run the simulated microcontroller by hand against a host (``reloc run --serial ...``)."""

from __future__ import annotations

import json
import time

import click


@click.command("firmware-sim")
@click.option("--port", "port_spec", default="pty", show_default=True,
              help="pty (prints the path to give the host), pty:LINK_PATH (a stable symlink to the pty), "
                   "tcp-listen:[HOST:]PORT (host connects with socket://HOST:PORT), or a pyserial URL / device.")
@click.option("--baudrate", type=int, default=921600, show_default=True, help="Baud rate when --port is a device.")
@click.option("--duration-s", type=float, default=0.0, show_default=True, help="Stop after this long (0 = Ctrl-C).")
@click.option("--odom-rate-hz", type=float, default=50.0, show_default=True)
@click.option("--heartbeat-period-s", type=float, default=0.5, show_default=True)
@click.option("--reloc-period-s", type=float, default=5.0, show_default=True,
              help="Ask for a relocalization this often once the host is alive (0 = never).")
@click.option("--trajectory", type=click.Choice(["figure8", "robot", "handheld"]), default="figure8", show_default=True,
              help="Ground-truth path: a figure-eight, or a simulator trajectory through --scene (base pose from the "
                   "camera poses and camera.T_base_cam of --config).")
@click.option("--scene", default="living_room", show_default=True, help="Scene of a simulator trajectory.")
@click.option("--frames", type=int, default=3000, show_default=True, help="Length of a simulator trajectory...")
@click.option("--rate-hz", type=float, default=30.0, show_default=True, help="...sampled at this rate.")
@click.option("--trajectory-seed", type=int, default=0, show_default=True, help="Seed of the scene and trajectory.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
              help="Config file (camera.T_base_cam); defaults otherwise.")
@click.option("--clock-drift-ppm", type=float, default=30.0, show_default=True, help="MCU clock rate error.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of odometry noise and faults.")
@click.option("--pose-tolerance-m", type=float, default=0.05, show_default=True,
              help="A received pose within this of the ground truth counts as correct...")
@click.option("--pose-tolerance-deg", type=float, default=2.0, show_default=True, help="...and within this heading.")
@click.option("--bit-error-rate", type=float, default=0.0, show_default=True, help="Fault: per-bit flip probability.")
@click.option("--drop-rate", type=float, default=0.0, show_default=True, help="Fault: per-frame drop probability.")
@click.option("--garbage-rate", type=float, default=0.0, show_default=True,
              help="Fault: per-frame probability of a burst of random bytes before it.")
@click.option("--unknown-rate", type=float, default=0.0, show_default=True,
              help="Fault: per-frame probability of an extra frame of unknown type or version.")
@click.option("--oversize-rate", type=float, default=0.0, show_default=True,
              help="Fault: per-frame probability of an oversize run of bytes.")
@click.option("--silent-after-s", type=float, default=None, help="Fault: stop sending after this long...")
@click.option("--silent-for-s", type=float, default=0.0, show_default=True, help="...for this long, then resume.")
@click.option("--flood-hz", type=float, default=0.0, show_default=True, help="Fault: send odometry at this rate.")
@click.option("--report-period-s", type=float, default=2.0, show_default=True, help="Print counters this often.")
@click.option("--json-out", type=click.Path(dir_okay=False), default=None, help="Write the final counters here.")
def firmware_sim(port_spec: str, baudrate: int, duration_s: float, odom_rate_hz: float, heartbeat_period_s: float,
                 reloc_period_s: float, trajectory: str, scene: str, frames: int, rate_hz: float,
                 trajectory_seed: int, config_path: str | None, clock_drift_ppm: float, seed: int, pose_tolerance_m: float,
                 pose_tolerance_deg: float, bit_error_rate: float, drop_rate: float, garbage_rate: float,
                 unknown_rate: float, oversize_rate: float, silent_after_s: float | None, silent_for_s: float,
                 flood_hz: float, report_period_s: float, json_out: str | None) -> None:
    """Simulated robot firmware: drives a figure-eight, sends wheel odometry and heartbeats, asks for
    relocalization and checks the poses it gets back against its ground truth."""
    from reloc.atomic import atomic_write_text

    from .mcu_sim import FaultInjector, McuSimulator, PlanarPath, open_endpoint

    path = PlanarPath() if trajectory == "figure8" else _simulator_path(
        trajectory, scene, frames, rate_hz, trajectory_seed, config_path)
    endpoint = open_endpoint(port_spec, baudrate=baudrate)
    faults = FaultInjector(seed=seed, bit_error_rate=bit_error_rate, drop_rate=drop_rate, garbage_rate=garbage_rate,
                           unknown_rate=unknown_rate, oversize_rate=oversize_rate)
    sim = McuSimulator(endpoint, path=path, odom_rate_hz=odom_rate_hz, heartbeat_period_s=heartbeat_period_s,
                       reloc_period_s=reloc_period_s, clock_drift_ppm=clock_drift_ppm, seed=seed,
                       pose_tolerance_m=pose_tolerance_m, pose_tolerance_deg=pose_tolerance_deg, faults=faults,
                       silent_after_s=silent_after_s, silent_for_s=silent_for_s, flood_hz=flood_hz)
    click.echo(f"simulated firmware on {endpoint.path}  (host: reloc run --serial {endpoint.path})", err=True)
    sim.start()
    end = None if duration_s <= 0 else time.monotonic() + duration_s
    try:
        while end is None or time.monotonic() < end:
            time.sleep(min(report_period_s, max(0.0, (end or float("inf")) - time.monotonic())))
            if sim.error:
                raise click.ClickException(f"simulator stopped: {sim.error}")
            s = sim.stats()
            d = s["decoder"]
            click.echo(
                f"odom {s['odometry_sent']}  hb {s['heartbeats_sent']}/{s['host_heartbeats']}  "
                f"req {s['requests_sent']} (acked {s['requests_acked']}, retx {s['request_retransmissions']})  "
                f"poses ok {s['poses_ok']} bad {s['poses_bad']} rejected {s['poses_rejected']}  "
                f"rx good {d['frames_good']} bad {d['frames_bad']}  host state {sim.host_state}",
                err=True,
            )
    except KeyboardInterrupt:
        pass
    finally:
        sim.stop()
    stats = sim.stats()
    click.echo(json.dumps(stats, indent=2, default=str))
    if json_out:
        atomic_write_text(json_out, json.dumps(stats, indent=2, default=str) + "\n")


def _simulator_path(trajectory: str, scene: str, frames: int, rate_hz: float, seed: int, config_path: str | None):
    """The base's path along a simulator camera trajectory (the same poses ``reloc sim`` renders)."""
    import numpy as np

    from reloc.config import load_config
    from sim.scenes import make_scene
    from sim.trajectories import make_trajectory

    from .mcu_sim import SampledPath

    cfg = load_config(config_path)
    T_world_cam = make_trajectory(trajectory, make_scene(scene, seed=seed), frames, seed, rate_hz=rate_hz)
    return SampledPath.from_T_world_cam(T_world_cam, rate_hz, np.asarray(cfg.camera.T_base_cam).reshape(4, 4))
