"""Soak: the live loop on the simulator with the simulated firmware for a long run, with faults injected.

What runs (all in this process, as ``reloc run --follow-firmware`` wires it across two):

- the simulated firmware (:class:`firmware_bridge.mcu_sim.McuSimulator`) drives the robot around a figure-eight in
  the living room, sends wheel odometry (50 Hz) and heartbeats, asks for a relocalization every 5 s and checks every
  pose it receives against its ground truth; it talks to the host over a pseudo-terminal;
- the host bridge (:class:`firmware_bridge.HostBridge`) opens that pty like a USB serial device;
- a simulated depth camera on the robot renders the room from the firmware's true base pose at each capture time
  (``--width`` x ``--height``, stereo noise, paced at ``--rate`` Hz) and carries that pose as ground truth;
- the live loop (:class:`reloc.live.loop.LiveLoop`) with the simulator's ground-truth planes of each frame
  (``--planes truth``, default: :class:`reloc.live.factory.TruthPlanes`) or real plane extraction (``--planes
  extract``), submaps of ``--window`` frames fused with the bridge's wheel odometry, the tracking check and
  relocalization in the exact map of the scene. Ground-truth planes are the default because at the resolutions a
  100,000-frame run allows on 2 shared cores (160x100, 320x200) extracted submaps along this path rarely hold enough
  planes to relocalize (a 1,500-frame run at 320x200: 1 of 80 attempts relocalized), which would leave the
  relocalization figures empty; the loop, the link, the faults and the memory are exercised the same way.

Faults injected at stated rates (see ``--help``): camera frames dropped, all-invalid frames, stalls, disconnects
(:class:`drivers.faults.FaultySource`); serial garbage bursts (:class:`firmware_bridge.mcu_sim.FaultInjector`) and
unplugs in the middle of a frame (:meth:`McuSimulator.unplug` / :meth:`~McuSimulator.plug`).

Reported: frames delivered, processed, dropped and rejected with reasons; relocalizations attempted, correct and
false (a relocalized pose off its ground truth by more than 0.1 m or 2 deg; there must be none); what the firmware
saw; resident memory sampled over the run (first vs last 10 %, and a slope); latency percentiles (capture -> planes,
capture -> pose, relocalization) over the first and the last 10 % of the run.

    python benchmarks/soak.py                # 100,000 frames (about 58 min at 30 Hz)
    python benchmarks/soak.py --quick        # 3,000 frames, a smoke run
Writes benchmarks/results/soak.json (soak_quick.json with ``--quick``; ``--out NAME`` for another name).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, results_name, write_results  # noqa: E402

from reloc.profiling import Profiler  # noqa: E402

FALSE_RELOC_M = 0.1
FALSE_RELOC_DEG = 2.0


@dataclass(frozen=True)
class SoakFaults:
    """Fault rates of a soak run. Camera: per-frame probabilities, and a disconnect every ``camera_disconnect_every``
    frames (0 = none; the first reconnect attempt after each fails). Serial: a garbage burst (1-64 random bytes)
    before each frame the firmware sends with probability ``serial_garbage_rate``, and an unplug in the middle of a
    frame every ``serial_unplug_every_s`` seconds (0 = none) for ``serial_unplug_down_s``."""

    camera_drop_rate: float = 0.01
    camera_invalid_rate: float = 0.005
    camera_stall_rate: float = 0.0005
    camera_stall_s: float = 1.5
    camera_disconnect_every: int = 10_000
    serial_garbage_rate: float = 0.01
    serial_unplug_every_s: float = 120.0
    serial_unplug_down_s: float = 1.0


def rss_mb() -> float:
    """Resident set size of this process, MB (/proc/self/status)."""
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


class SeriesProfiler(Profiler):
    """A :class:`Profiler` that also keeps every sample (end time, duration) of a few stages, in arrays allocated
    and touched up front so that keeping them does not show as memory growth."""

    def __init__(self, names, capacity: int, **kwargs):
        super().__init__(**kwargs)
        self.series = {n: np.full((capacity, 2), -1, dtype=np.int64) for n in names}
        self.counts = dict.fromkeys(names, 0)

    def record(self, name, start_ns, duration_ns, thread=None):
        super().record(name, start_ns, duration_ns, thread)
        arr = self.series.get(name)
        if arr is not None:  # each series is written by one thread only
            i = self.counts[name]
            if i < len(arr):
                arr[i] = (start_ns + duration_ns, duration_ns)
                self.counts[name] = i + 1

    def samples(self, name):
        a = self.series[name][: self.counts[name]]
        return a[:, 0], a[:, 1]


class _Tally(deque):
    """The firmware's pose-check log, counting every check by status, outcome and stamp (a pose stamped in the MCU
    clock is checked at its stamp; one sent before the host knows that clock, at its arrival) as it is appended."""

    def __init__(self, maxlen: int, mcu_counters: dict):
        super().__init__(maxlen=maxlen)
        self.counts: Counter = Counter()
        self.max_error: dict = {}
        self.off_ok: list = []  # the first relocalized (OK) poses off the firmware's ground truth
        self._mcu_counters = mcu_counters
        self._unsynced_seen = 0

    def append(self, check):
        from firmware_bridge.messages import PoseStatus

        unsynced = self._mcu_counters["poses_unsynced"]  # counted by the firmware just before this check
        stamp = "at_arrival" if unsynced != self._unsynced_seen else "at_stamp"
        self._unsynced_seen = unsynced
        name = {PoseStatus.OK: "ok", PoseStatus.TRACKED: "tracked"}.get(check.status, "rejected")
        if name == "rejected":
            self.counts["rejected"] += 1
        else:
            self.counts[f"{name}:{stamp}:{'good' if check.ok else 'off'}"] += 1
            if math.isfinite(check.position_error_m):
                m, d = self.max_error.get(f"{name}:{stamp}", (0.0, 0.0))
                self.max_error[f"{name}:{stamp}"] = (max(m, check.position_error_m), max(d, check.yaw_error_deg))
            if name == "ok" and not check.ok and len(self.off_ok) < 20:
                self.off_ok.append({"request_id": check.request_id, "stamp": stamp,
                                    "position_error_m": check.position_error_m, "yaw_error_deg": check.yaw_error_deg,
                                    "latency_ms": None if check.latency_ns is None else check.latency_ns / 1e6})
        super().append(check)


def _robot_camera(mcu, scene, T_base_cam, width: int, height: int, rate_hz: float, seed: int):
    """A depth camera on the simulated robot: each frame rendered from the firmware's true base pose at the moment it
    is taken, stamped with the host clock, with that pose as ground truth."""
    from drivers.source import FrameSource, Pacer
    from reloc.camera import DepthFrame
    from sim.cameras import resolve_intrinsics
    from sim.noise import make_noise
    from sim.render import render
    from sim.trajectories import gravity_in_camera

    intr = resolve_intrinsics("oak-d", width, height)
    noise = make_noise("stereo")

    class RobotCamera(FrameSource):
        name = f"robot-camera({width}x{height})"

        @property
        def intrinsics(self):
            return intr

        @property
        def rate_hz(self):
            return rate_hz

        def noise_law(self):
            return noise.extraction_law(intr.fx)

        def _frames(self):
            pacer = Pacer(rate_hz)
            seq = 0
            while not self.closed:
                pacer.wait(0)
                now = time.monotonic_ns()
                T = mcu.true_T_map_base_at_host(now) @ T_base_cam
                depth, labels = render(scene, intr, T)
                depth, labels = noise.apply(depth, labels, intr, np.random.default_rng([seed, seq]))
                yield DepthFrame(depth, intr, now, seq, T_world_cam=T, gravity_cam=gravity_in_camera(T),
                                 pose_source="groundtruth", labels=labels)
                seq += 1

    return RobotCamera()


def _percentiles(durations_ns) -> dict | None:
    if len(durations_ns) == 0:
        return None
    ms = np.asarray(durations_ns, dtype=np.float64) / 1e6
    return {"count": int(ms.size), "p50_ms": float(np.percentile(ms, 50)), "p95_ms": float(np.percentile(ms, 95)),
            "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max())}


def run_soak(n_frames: int, *, width: int = 160, height: int = 100, rate_hz: float = 30.0, planes: str = "truth",
             window_frames: int = 3, faults: SoakFaults = SoakFaults(), seed: int = 0, scene_name: str = "living_room",
             progress=None, rss_period_s: float = 1.0) -> dict:
    """Run the soak (module docstring) for ``n_frames`` captured frames; returns the counts and figures (a dict).

    ``progress(line)`` receives the loop's status line every few seconds (None: silent).
    """
    from drivers.faults import FaultySource
    from firmware_bridge import HostBridge
    from firmware_bridge.mcu_sim import FaultInjector, McuSimulator, PlanarPath, PtyEndpoint
    from reloc.config import Config
    from reloc.live.factory import (
        load_plane_map,
        make_extractor,
        make_relocalizer,
        make_submap_fuser,
        with_camera_noise,
    )
    from reloc.live.loop import THREAD_NAMES, LiveLoop
    from reloc.live.params import LiveParams
    from sim.scenes import make_scene

    if n_frames < 1:
        raise ValueError(f"n_frames: expected >= 1, got {n_frames}")
    cfg = Config()
    T_base_cam = np.asarray(cfg.camera.T_base_cam, dtype=np.float64).reshape(4, 4)
    scene = make_scene(scene_name)
    map_planes, plane_map = load_plane_map(f"sim:{scene_name}")
    # A figure-eight through the living room along which the camera sees enough of the room most of the time.
    path = PlanarPath(center_m=(3.0, 1.8), amplitude_m=(1.5, 1.0), period_s=30.0)

    tmp = tempfile.TemporaryDirectory(prefix="soak-")
    link = os.path.join(tmp.name, "ttyMCU")
    serial_faults = FaultInjector(seed=seed + 1, garbage_rate=faults.serial_garbage_rate)
    mcu = McuSimulator(PtyEndpoint(link), path=path, reloc_period_s=5.0, odom_rate_hz=50.0, seed=seed,
                       pose_tolerance_m=FALSE_RELOC_M, pose_tolerance_deg=FALSE_RELOC_DEG, faults=serial_faults)
    mcu.pose_checks = _Tally(maxlen=1000, mcu_counters=mcu.counters)
    bridge = HostBridge(link, reconnect_backoff_s=(0.05, 0.1, 0.2, 0.5), pose_rate_hz=10.0)
    camera = _robot_camera(mcu, scene, T_base_cam, width, height, rate_hz, seed)
    cfg, _ = with_camera_noise(cfg, camera)  # as reloc run does: the camera's stereo law
    relocalizer = make_relocalizer(plane_map, cfg)
    extract = make_extractor(cfg, planes=planes, scene=scene)
    every = faults.camera_disconnect_every
    source = FaultySource(camera, drop_rate=faults.camera_drop_rate, invalid_rate=faults.camera_invalid_rate,
                          stall_rate=faults.camera_stall_rate, stall_s=faults.camera_stall_s,
                          disconnect_at=range(every, n_frames * 2, every) if every else (), reconnect_failures=1,
                          seed=seed + 2)
    params = LiveParams.from_config(cfg, window_frames=window_frames, queue_frames=8, search_period_s=0.25,
                                    reconnect_backoff_s=(0.05, 0.1, 0.2))
    stages = ("latency.capture_to_planes", "latency.capture_to_pose", "reloc", "extract")
    prof = SeriesProfiler(stages, capacity=n_frames + 16)

    # Compile and warm up outside the measurement (numba kernels, first-use allocations).
    from reloc._numba import warm_up

    warm_up(("reloc.matching._kernels",))
    warm = next(iter(_robot_camera(_FixedPose(path, T_base_cam), scene, T_base_cam, width, height, 1000.0, seed)))
    relocalizer.locate(extract(warm).planes)

    status_lines: list[str] = []

    def on_status(line):
        status_lines.append(line)
        if progress is not None and len(status_lines) % 30 == 0:
            progress(line)

    loop = LiveLoop(source, extract, relocalizer, params=params, map_planes=map_planes, bridge=bridge,
                    odometry="auto", profiler=prof, on_status=on_status, fuse_submap=make_submap_fuser(cfg))

    # Background: resident memory samples (arrays allocated up front), relocalization outcomes by index (the loop
    # keeps only its latest records), serial unplugs on schedule.
    done = threading.Event()
    rss_cap = 20_000
    rss = np.full((rss_cap, 2), np.nan)
    rss_n = [0]
    relocs = {"seen": -1, "ok": 0, "correct": 0, "false": [], "rejected": Counter(), "triggers": Counter(),
              "max_error_m": 0.0, "max_error_deg": 0.0, "ok_without_truth": 0}
    unplug_log = []

    def sample_rss():
        t0 = time.monotonic()
        period = rss_period_s
        while not done.wait(period):
            i = rss_n[0]
            if i >= rss_cap:  # a run longer than planned: keep every other sample and halve the rate
                rss[: rss_cap // 2] = rss[0:rss_cap:2]
                i = rss_n[0] = rss_cap // 2
                period *= 2
            rss[i] = (time.monotonic() - t0, rss_mb())
            rss_n[0] = i + 1

    def tally_relocs():
        while True:
            stop = done.wait(2.0)
            for r in loop.records():
                if r.index <= relocs["seen"]:
                    continue
                relocs["seen"] = r.index
                relocs["triggers"][r.trigger.split("+")[-1]] += 1
                if not r.ok:
                    relocs["rejected"][r.reason.split(":")[0][:60]] += 1
                    continue
                relocs["ok"] += 1
                if r.position_error_m is None:
                    relocs["ok_without_truth"] += 1
                    continue
                relocs["max_error_m"] = max(relocs["max_error_m"], r.position_error_m)
                relocs["max_error_deg"] = max(relocs["max_error_deg"], r.rotation_error_deg)
                if r.position_error_m > FALSE_RELOC_M or r.rotation_error_deg > FALSE_RELOC_DEG:
                    relocs["false"].append(r.to_dict())
                else:
                    relocs["correct"] += 1
            if stop:
                return

    def unplugs():
        period = faults.serial_unplug_every_s
        if not period:
            return
        while not done.wait(period):
            t = time.monotonic()
            mcu.unplug(mid_frame=True)
            if done.wait(faults.serial_unplug_down_s):
                return
            mcu.plug(PtyEndpoint(link))
            unplug_log.append(round(t - t_start, 1))

    workers = [threading.Thread(target=f, name=f"soak-{f.__name__}", daemon=True)
               for f in (sample_rss, tally_relocs, unplugs)]
    t_start = time.monotonic()
    rss_start = rss_mb()
    mcu.start()
    bridge.start()
    for w in workers:
        w.start()
    try:
        summary = loop.run(max_frames=n_frames)
    finally:
        done.set()
        for w in workers:
            w.join()
        mcu_stats = mcu.stats()
        bridge_stats = bridge.stats()
        bridge.close()
        mcu.stop()
        source.close()
        tmp.cleanup()
    duration = time.monotonic() - t_start
    leftover_threads = [t.name for t in threading.enumerate() if t.name in THREAD_NAMES]

    s = summary.to_dict()
    f = s["frames"]
    bad = dict(f["bad"])
    delivered = source.counts["frames_out"]

    # Latency over the first and the last 10 % of the run (by time since the loop started).
    lat = {}
    for name in stages:
        ends, durs = prof.samples(name)
        if len(ends) == 0:
            lat[name] = {"all": None, "first_10pct": None, "last_10pct": None}
            continue
        lo, hi = ends.min(), ends.max()
        span = max(hi - lo, 1)
        first = durs[ends <= lo + span // 10]
        last = durs[ends >= hi - span // 10]
        lat[name] = {"all": _percentiles(durs), "first_10pct": _percentiles(first), "last_10pct": _percentiles(last)}

    # Memory: first vs last 10 % of the samples, and a least-squares slope over the run after its first 10 %.
    r = rss[: rss_n[0]]
    mem = {"start_mb": rss_start, "samples": int(len(r))}
    if len(r) >= 10:
        k = max(1, len(r) // 10)
        first, last = r[:k, 1], r[-k:, 1]
        tail = r[k:]
        slope = float(np.polyfit(tail[:, 0], tail[:, 1], 1)[0]) if len(tail) >= 3 else float("nan")
        mem.update(first_10pct_mean_mb=float(first.mean()), last_10pct_mean_mb=float(last.mean()),
                   growth_pct=float(100 * (last.mean() - first.mean()) / first.mean()),
                   max_mb=float(r[:, 1].max()), slope_mb_per_hour=slope * 3600,
                   series=[[round(float(t), 1), round(float(m), 2)] for t, m in r[:: max(1, len(r) // 200)]])

    return {
        "frames_requested": n_frames,
        "duration_s": duration,
        "cpu_s": s["cpu_s"],
        "frames": {
            "delivered": delivered, "captured": f["captured"], "processed": f["processed"],
            "with_planes": f["with_planes"], "dropped_by_queue": f["dropped"], "bad": bad,
            "bad_total": int(sum(bad.values())), "missing_from_source": f["source_gaps"],
            "queue_max_depth": f["queue_max_depth"], "fps": f["fps"],
        },
        "camera_faults_injected": dict(source.counts),
        "source_events": {k: v for k, v in s["source_events"].items() if k != "events"},
        "relocalizations": {
            "attempted": summary.relocs_count, "relocalized": summary.relocs_ok,
            "rejected": summary.relocs_count - summary.relocs_ok,
            "checked": relocs["ok"], "correct": relocs["correct"], "false": len(relocs["false"]),
            "false_records": relocs["false"][:20], "ok_without_truth": relocs["ok_without_truth"],
            "max_position_error_m": relocs["max_error_m"], "max_rotation_error_deg": relocs["max_error_deg"],
            "rejection_reasons": dict(relocs["rejected"]), "triggers": dict(relocs["triggers"]),
        },
        "tracking": s["tracking"], "odometry": s["odometry"],
        "firmware": {
            "pose_checks": dict(mcu.pose_checks.counts),
            "pose_max_error_m_deg": mcu.pose_checks.max_error,
            "ok_poses_off": mcu.pose_checks.off_ok,
            "poses_unsynced": mcu_stats.get("poses_unsynced"),
            **{k: mcu_stats.get(k) for k in ("requests_sent", "requests_acked", "requests_failed",
                                             "requests_unanswered", "poses_received", "unplugs",
                                             "half_frames_sent", "connections", "write_failures")},
            "serial_faults_injected": dict(serial_faults.counts),
            "decoder": mcu_stats["decoder"],
        },
        "host_bridge": {k: bridge_stats.get(k) for k in (
            "connects", "disconnects", "open_failures", "frames_good", "crc_errors", "framing_errors", "oversize",
            "truncated", "frames_bad", "resyncs", "frames_lost", "odometry", "heartbeats_in", "mcu_timeouts",
            "mcu_reboots", "reloc_requests", "answers_sent", "poses_sent", "poses_failed", "events_dropped")},
        "loop_serial_errors": (s["bridge"] or {}).get("loop_serial_errors"),
        "serial_unplugs_at_s": unplug_log,
        "latency": lat,
        "stages_ms": {k: {q: round(v[q], 3) for q in ("count", "p50_ms", "p99_ms", "mean_ms")}
                      for k, v in prof.summary()["stages"].items() if not k.startswith(("reloc.", "extract."))},
        "memory": mem,
        "errors": s["errors"],
        "threads_left_running": leftover_threads,
    }


class _FixedPose:
    """Stands in for the firmware during warm-up (the camera only asks it for the true pose)."""

    def __init__(self, path, T_base_cam):
        self.path = path

    def true_T_map_base_at_host(self, host_ns):
        return self.path.T_map_base(0.0)


def check_counts(res: dict) -> list[str]:
    """The identities a soak must satisfy; returns the ones that do not hold (empty: all good)."""
    f = res["frames"]
    problems = []
    if f["captured"] != f["delivered"]:
        problems.append(f"captured {f['captured']} != delivered {f['delivered']}")
    if f["processed"] + f["dropped_by_queue"] != f["captured"]:
        problems.append(f"processed {f['processed']} + dropped {f['dropped_by_queue']} != captured {f['captured']}")
    if f["with_planes"] + f["bad_total"] != f["processed"]:
        problems.append(f"with planes {f['with_planes']} + bad {f['bad_total']} != processed {f['processed']}")
    if f["bad"].get("no_valid_depth", 0) > res["camera_faults_injected"]["invalid"]:
        problems.append("more frames without depth than injected")
    rel = res["relocalizations"]
    if rel["false"]:
        problems.append(f"{rel['false']} false relocalizations")
    if rel["checked"] != rel["relocalized"]:
        problems.append(f"relocalized {rel['relocalized']} but {rel['checked']} checked against ground truth")
    if res["errors"] or res["threads_left_running"]:
        problems.append(f"errors {res['errors']}, threads left {res['threads_left_running']}")
    return problems


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=100_000, help="Frames captured (default 100000).")
    ap.add_argument("--quick", action="store_true", help="A smoke run of 3,000 frames (overrides --frames).")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=100)
    ap.add_argument("--rate", type=float, default=30.0, help="Camera frame rate, Hz.")
    ap.add_argument("--planes", choices=["extract", "truth"], default="truth")
    ap.add_argument("--window", type=int, default=3, help="Frames per submap (fused with the wheel odometry).")
    ap.add_argument("--seed", type=int, default=0)
    d = SoakFaults()
    for name in SoakFaults.__dataclass_fields__:
        ap.add_argument("--" + name.replace("_", "-"), type=type(getattr(d, name)), default=getattr(d, name))
    ap.add_argument("--out", default=None, help="Results file stem under benchmarks/results (default soak, or "
                                                "soak_quick with --quick).")
    args = ap.parse_args(argv)
    out = args.out or ("soak_quick" if args.quick else "soak")
    try:
        results_name(out, "--out")  # before the run, not after it
    except ValueError as e:
        ap.error(str(e))
    n = 3000 if args.quick else args.frames
    faults = SoakFaults(**{k: getattr(args, k) for k in SoakFaults.__dataclass_fields__})
    if args.quick and faults.camera_disconnect_every > n // 2:
        faults = SoakFaults(**{**faults.__dict__, "camera_disconnect_every": 1000, "serial_unplug_every_s": 15.0})
    print(f"soak: {n} frames {args.width}x{args.height} at {args.rate} Hz, {args.planes} planes, submaps of "
          f"{args.window} frames; faults {faults}", flush=True)
    res = run_soak(n, width=args.width, height=args.height, rate_hz=args.rate, planes=args.planes,
                   window_frames=args.window, faults=faults, seed=args.seed,
                   progress=lambda line: print("  " + line, flush=True))
    f, rel, mem, fw, hb = res["frames"], res["relocalizations"], res["memory"], res["firmware"], res["host_bridge"]
    print_table(["frames", "count"], [
        ["delivered by the camera", f["delivered"]], ["processed", f["processed"]],
        ["  with planes", f["with_planes"]], ["  bad (rejected)", f"{f['bad_total']} {f['bad']}"],
        ["dropped by the queue", f["dropped_by_queue"]], ["missing from the source (gaps)", f["missing_from_source"]],
        ["camera faults injected", str({k: v for k, v in res["camera_faults_injected"].items()
                                        if k not in ("frames_in", "frames_out")})],
        ["source events", str(res["source_events"])],
    ], title=f"soak: {n} frames in {res['duration_s'] / 60:.1f} min ({f['fps']} fps processed)")
    print_table(["relocalizations", "count"], [
        ["attempted", rel["attempted"]], ["relocalized", rel["relocalized"]], ["  correct (<= 0.1 m, 2 deg)",
                                                                               rel["correct"]],
        ["  FALSE (> 0.1 m or 2 deg)", rel["false"]], ["rejected", f"{rel['rejected']} {rel['rejection_reasons']}"],
        ["max error of relocalized", f"{rel['max_position_error_m']:.3f} m, {rel['max_rotation_error_deg']:.2f} deg"],
        ["triggers", str(rel["triggers"])], ["tracking", str(res["tracking"]["lost"])],
        ["firmware pose checks", str(fw["pose_checks"])],
        ["firmware requests sent/acked/failed/unanswered",
         f"{fw['requests_sent']}/{fw['requests_acked']}/{fw['requests_failed']}/{fw['requests_unanswered']}"],
        ["serial: unplugs, garbage bursts", f"{fw['unplugs']}, {fw['serial_faults_injected']['garbage_bursts']}"],
        ["host link: connects/disconnects/open failures",
         f"{hb['connects']}/{hb['disconnects']}/{hb['open_failures']}"],
        ["host decoder: good, bad (crc, framing, truncated)",
         f"{hb['frames_good']}, {hb['frames_bad']} ({hb['crc_errors']}, {hb['framing_errors']}, {hb['truncated']})"],
    ])
    rows = []
    for name, label in (("latency.capture_to_planes", "capture -> planes"), ("latency.capture_to_pose",
                                                                             "capture -> pose"), ("reloc", "reloc"),
                        ("extract", "extract")):
        for part in ("first_10pct", "last_10pct"):
            p = res["latency"][name][part]
            rows.append([f"{label} ({part.replace('_10pct', ' 10%')})", *(None if p is None else p[k] for k in
                                                                           ("count", "p50_ms", "p95_ms", "p99_ms",
                                                                            "max_ms"))])
    print_table(["latency", "count", "p50 ms", "p95 ms", "p99 ms", "max ms"], rows,
                floatfmt=[None, None, ".2f", ".2f", ".2f", ".1f"])
    if "growth_pct" in mem:
        print(f"RSS: start {mem['start_mb']:.0f} MB, first 10% {mem['first_10pct_mean_mb']:.1f} MB, last 10% "
              f"{mem['last_10pct_mean_mb']:.1f} MB ({mem['growth_pct']:+.2f} %), max {mem['max_mb']:.1f} MB, slope "
              f"{mem['slope_mb_per_hour']:+.2f} MB/h over {mem['samples']} samples")
    print("stages (whole run): " + ", ".join(f"{k} p50 {v['p50_ms']:.2f} ms" for k, v in res["stages_ms"].items()))
    problems = check_counts(res)
    print("counts consistent, no false relocalization" if not problems else f"PROBLEMS: {problems}")
    params = {**vars(args), "frames": n, "faults": faults.__dict__,
              "note": "timings on a shared 2-core machine (other jobs running): expect noise"}
    path = write_results(out, params=params, results=res)
    print(f"wrote {path}")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
