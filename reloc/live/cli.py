"""``reloc run``: the live loop from the command line."""

from __future__ import annotations

import signal

import click


class StartupSignals:
    """SIGINT and SIGTERM while a command starts up: each raises ``KeyboardInterrupt`` (the command aborts and
    writes nothing) and is remembered, since Python drops an exception raised in a handler that happens to run
    inside a finalizer (numba collects garbage while it compiles the kernels; the signal was then lost and the loop
    ran on). :meth:`check` raises it again where start-up ends; :meth:`restore` puts back the previous handlers."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: list[int] = []
        self.previous = {s: signal.signal(s, self._handler) for s in self.SIGNALS}

    def _handler(self, signum, _frame):
        self.received.append(signum)
        raise KeyboardInterrupt(f"signal {signum}")

    def check(self) -> None:
        if self.received:
            raise KeyboardInterrupt(f"signal {self.received[0]} during start-up")

    def restore(self) -> None:
        for s, h in self.previous.items():
            signal.signal(s, h)


@click.command("run")
@click.option("--camera", "camera", required=True, metavar="SOURCE",
              help="Frame source: sim[:SCENE], oak[:DEVICE_ID], replay:DIR (a recorded or written sequence).")
@click.option("--map", "map_spec", required=True, metavar="MAP",
              help="Plane map file from `reloc map`, or sim:SCENE for the exact map of a simulated scene.")
@click.option("--serial", "serial_url", default=None, metavar="URL",
              help="Firmware link (pyserial URL: /dev/ttyACM0, socket://HOST:PORT, a pty path); default serial.url.")
@click.option("--frames", type=click.IntRange(min=1), default=None, help="Stop after this many captured frames.")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Stop after this many seconds.")
@click.option("--summary", "summary_path", type=click.Path(dir_okay=False), default=None,
              help="Write the run summary (JSON) here.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("--rate", default=None, metavar="RATE",
              help="Pace of simulated/replayed frames: recorded, fast, or Hz (default: live.realtime).")
@click.option("--odometry", type=click.Choice(["auto", "bridge", "source", "none"]), default="auto", show_default=True,
              help="Submap poses: auto = firmware odometry, else the source's odometry; source = any frame pose "
                   "(ground truth included, for simulations); none = single-frame submaps.")
@click.option("--planes", type=click.Choice(["extract", "truth"]), default="extract", show_default=True,
              help="extract = plane extraction; truth = the simulator's ground-truth planes (sim camera only).")
@click.option("--trace", "trace_path", type=click.Path(dir_okay=False), default=None,
              help="Write a Chrome trace (one track per thread) of the run here.")
@click.option("--follow-firmware", is_flag=True,
              help="With --camera sim:SCENE and --serial: render from the simulated firmware's robot (reloc "
                   "firmware-sim --trajectory robot --scene SCENE), on its clock, so its pose checks hold.")
@click.option("--firmware-frames", type=int, default=3000, show_default=True,
              help="With --follow-firmware: the firmware simulator's --frames (its trajectory length).")
@click.option("--quiet", is_flag=True, help="No status line.")
def run(camera, map_spec, serial_url, frames, duration_s, summary_path, config_path, rate, odometry, planes,
        trace_path, follow_firmware, firmware_frames, quiet):
    """Relocalize live: frames -> planes -> submaps -> poses, with odometry in and poses out over serial.

    Ctrl-C or SIGTERM stop cleanly (threads joined, the summary and trace written). On a terminal, Enter asks
    for a relocalization and `q` Enter quits.
    """
    import json
    import sys

    from drivers.source import SourceError
    from reloc.atomic import atomic_write_text
    from reloc.config import config_as_dict, load_config
    from reloc.live.factory import (
        load_plane_map,
        make_bridge,
        make_extractor,
        make_relocalizer,
        make_submap_fuser,
        open_camera,
        with_camera_noise,
    )
    from reloc.live.loop import LiveLoop
    from reloc.live.params import LiveParams
    from reloc.profiling import Profiler

    cfg = load_config(config_path)
    if frames is not None and duration_s is not None:
        raise click.UsageError("give --frames or --duration, not both")
    url = serial_url if serial_url is not None else cfg.serial.url
    echo = (lambda line: None) if quiet else (lambda line: click.echo(line, err=True))

    if follow_firmware and (not url or camera.partition(":")[0] != "sim"):
        raise click.UsageError("--follow-firmware needs --camera sim[:SCENE] and a serial link (--serial)")
    startup = StartupSignals()
    bridge = source = None
    try:
        map_planes, plane_map = load_plane_map(map_spec)
        echo(f"map: {len(map_planes)} planes from {map_spec}")
        if url:
            bridge = make_bridge(url, cfg)
            echo(f"serial: {url}")
        if follow_firmware:
            import numpy as np

            from reloc.live.sim_robot import FirmwareSyncedSimSource

            clock = bridge.clock
            source = FirmwareSyncedSimSource.like_firmware_sim(
                camera.partition(":")[2] or "living_room", firmware_frames,
                np.asarray(cfg.camera.T_base_cam).reshape(4, 4),
                lambda host_ns: clock.host_to_mcu_ns(host_ns) if clock.synced else None)
        else:
            try:
                source = open_camera(camera, cfg, rate=rate, n_frames=frames)
            except SourceError as exc:  # no device, device lost: the message says what to do
                raise click.ClickException(str(exc)) from None
        cfg, note = with_camera_noise(cfg, source)
        if note:
            echo(note)
        relocalizer = make_relocalizer(plane_map, cfg)
        extract = make_extractor(cfg, planes=planes, scene=getattr(source, "scene", None))
        _warm_up(extract, source)
        profiler = Profiler(trace_capacity=200_000 if trace_path else 0)
        loop = LiveLoop(source, extract, relocalizer, params=LiveParams.from_config(cfg), map_planes=map_planes,
                        bridge=bridge, odometry=odometry, profiler=profiler, on_status=echo,
                        keyboard=not quiet and sys.stdin is not None and sys.stdin.isatty(),
                        fuse_submap=make_submap_fuser(cfg))

        def on_signal(signum, _frame):
            echo(f"signal {signal.Signals(signum).name}: stopping")
            loop.stop()
            signal.signal(signum, signal.SIG_DFL)  # a second one ends the process the hard way

        startup.check()
        previous = {s: signal.signal(s, on_signal) for s in StartupSignals.SIGNALS}
        try:
            summary = loop.run(max_frames=frames, duration_s=duration_s)
        finally:
            for s, h in previous.items():
                signal.signal(s, h)
    finally:
        startup.restore()
        if bridge is not None:
            bridge.close()
        if source is not None:
            source.close()

    d = summary.to_dict()
    d["command"] = {"camera": camera, "map": map_spec, "serial": url or None, "frames": frames,
                    "duration_s": duration_s, "rate": rate, "odometry": odometry, "planes": planes, "config_file": config_path}
    d["config"] = config_as_dict(cfg)  # the resolved config that produced this run
    if summary_path:
        atomic_write_text(summary_path, json.dumps(d, indent=1) + "\n")
    if trace_path:
        profiler.write_chrome_trace(trace_path)
    if not quiet:
        click.echo(profiler.table(order=["capture.wait", "extract", "submap", "track", "submap.build", "reloc",
                                         "latency.capture_to_planes", "latency.capture_to_pose"]), err=True)
    f = d["frames"]
    click.echo(f"frames: {f['captured']} captured, {f['processed']} processed, {f['dropped']} dropped by the queue, "
               f"{f['source_gaps']} missing from the source, {sum(f['bad'].values())} bad {f['bad'] or ''}".rstrip())
    click.echo(f"relocalizations: {d['relocalizations_ok']} ok, {d['relocalizations_failed']} failed; "
               f"final state {d['tracking']['final_state']}; source {d['source_events']['end']}")
    if d["source_events"]["end"] == "disconnected":
        lost = [e for e in d["source_events"]["events"] if "source disconnected" in e]
        why = lost[-1].split("source disconnected: ", 1)[-1] if lost else "?"
        click.echo(f"camera lost and not reconnected: {why}", err=True)
    for e in d["errors"]:
        click.echo(f"error: {e}", err=True)


def _warm_up(extract, source) -> None:
    """Compile numba kernels before the timed run: every registered warm-up, then one call on a flat frame of the
    source's size."""
    import numpy as np

    from reloc._numba import warm_up
    from reloc.camera import DepthFrame

    warm_up(("reloc.matching._kernels",))

    intr = source.intrinsics
    try:
        extract(DepthFrame(np.full(intr.shape, 2.0, np.float32), intr, 0))
    except Exception:  # noqa: BLE001 - warm-up only; a real problem shows on the first real frame
        pass
