"""The live loop on the simulated camera: does it keep up with 30 Hz on this machine, and at what latency?

Frames: the simulated OAK-D class camera (640x400, stereo noise) along the robot trajectory through the living room,
delivered at 30 Hz (``--rate``) for ``--frames`` frames (>= 10,000 for the reported figure). The camera's frames are
rendered ahead into a pool (``--pool`` frames, played forward and back so the motion stays continuous): a real
camera computes depth on the device, while rendering here would take ~19 ms of the same CPU and GIL per frame and
measure the simulator instead of the loop. The loop does everything else live: plane extraction per frame,
submaps, the tracking check, relocalization at start-up / when lost / every ``live.reloc_period_s``.

Side by side in the same process (the same frames, extraction and relocalizer):
- ``realtime``: paced at ``--rate`` (the robot's situation): frames processed and dropped, end-to-end latency from
  capture to plane set and from capture to relocalized pose (p50/p95/p99), CPU use (process CPU seconds per wall
  second, i.e. cores busy), resident memory after warm-up and at the end (growth must stay under 5%).
- ``synchronous (baseline)``: one thread doing everything in turn on a camera with its own clock (``--sync-frames``):
  frames arriving while it extracts or relocalizes are lost, and a relocalization delays every frame behind it.
- ``fast``: the same frames as fast as the source gives them (``--fast-frames``), with a queue as long as the run
  so that none is dropped: the loop's capacity in frames per second (its latencies include queueing, so they are
  not the real-time figures).

    python benchmarks/live_loop.py                       # 10,000 frames at 30 Hz (about 6 minutes)
    python benchmarks/live_loop.py --frames 900          # a shorter run
Writes benchmarks/results/live_loop.json (or ``--out NAME``).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, results_name, write_results  # noqa: E402


def rss_mb() -> float:
    """Resident set size of this process now, MB (from /proc; falls back to the peak from getrusage)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def make_pool(scene: str, n: int, width: int, height: int, seed: int, keep_labels: bool):
    from drivers.sim_source import SimSource

    src = SimSource(scene, n_frames=n, camera="oak-d", width=width, height=height, seed=seed, rate="fast")
    pool = []
    for i in range(n):
        f = src.camera[i]
        pool.append(f if keep_labels else replace(f, labels=None))
    return src, pool


def pooled_source(pool, n_frames: int, rate):
    """A frame source playing ``pool`` forward and back (continuous motion) with fresh stamps and seq numbers."""
    from drivers.source import FrameSource, Pacer

    order = list(range(len(pool))) + list(range(len(pool) - 2, 0, -1))
    intr = pool[0].intrinsics

    class Pooled(FrameSource):
        name = f"sim-pool({len(pool)} frames)"

        @property
        def intrinsics(self):
            return intr

        @property
        def rate_hz(self):
            return rate if isinstance(rate, float) else None

        def _frames(self):
            pacer = Pacer(rate)
            period = int(round(1e9 / 30.0))
            for i in range(n_frames):
                if self.closed:
                    return
                f = pool[order[i % len(order)]]
                stamp = i * period
                pacer.wait(stamp)
                yield replace(f, stamp_ns=stamp, seq=i)

    return Pooled()


def run_once(label, pool, scene_obj, n_frames, rate, cfg, plane_map, map_planes, planes_mode, status_every,
             **overrides):
    from reloc.live.factory import make_extractor, make_relocalizer
    from reloc.live.loop import LiveLoop
    from reloc.live.params import LiveParams
    from reloc.profiling import Profiler

    extract = make_extractor(cfg, planes=planes_mode, scene=scene_obj)
    reloc = make_relocalizer(plane_map, cfg)
    # Warm up (JIT and first-use allocations) on pool frames, outside the measurement.
    for f in pool[:3]:
        reloc.locate(extract(f).planes)
    source = pooled_source(pool, n_frames, rate)
    rss = {"start": rss_mb(), "samples": []}
    prof = Profiler(window=max(16384, n_frames + 64))

    def on_status(line):
        rss["samples"].append(rss_mb())
        if status_every and len(rss["samples"]) % status_every == 0:
            print(f"  [{label}] {line}", flush=True)

    loop = LiveLoop(source, extract, reloc, params=LiveParams.from_config(cfg, **overrides), map_planes=map_planes,
                    odometry="source", profiler=prof, on_status=on_status)
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    summary = loop.run()
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    rss_end = rss_mb()
    source.close()
    s = summary.to_dict()
    stages = s["latency_ms"]
    ok = [r for r in summary.relocalizations if r.ok]
    errs = [r.position_error_m for r in ok if r.position_error_m is not None]
    rots = [r.rotation_error_deg for r in ok if r.rotation_error_deg is not None]
    cpu_s = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    # Growth is judged after the first tenth of the run (buffers reach their working size during warm-up frames).
    samples = rss["samples"]
    rss_settled = samples[max(0, len(samples) // 10 - 1)] if samples else rss["start"]

    def pct(d, key):
        return None if d is None else {k: d.get(k) for k in ("p50_ms", "p95_ms", "p99_ms", "max_ms", "count")}

    return {
        "mode": label,
        "rate": rate,
        "frames_requested": n_frames,
        "duration_s": s["duration_s"],
        "frames": s["frames"],
        "fps_processed": s["frames"]["fps"],
        "capture_to_planes_ms": pct(s["end_to_end_ms"]["capture_to_planes"], None),
        "capture_to_pose_ms": pct(s["end_to_end_ms"]["capture_to_pose"], None),
        "extract_ms": pct(stages.get("extract"), None),
        "reloc_ms": pct(stages.get("reloc"), None),
        "cpu_s": cpu_s,
        "cpu_cores_busy": cpu_s / s["duration_s"] if s["duration_s"] else None,
        "rss_mb": {"start": rss["start"], "settled": rss_settled, "end": rss_end, "max": max(samples + [rss_end]),
                   "growth_from_start": (rss_end - rss["start"]) / rss["start"],
                   "growth_from_settled": (rss_end - rss_settled) / rss_settled},
        "relocalizations": {"ok": len(ok), "failed": len(summary.relocalizations) - len(ok),
                            "triggers": _count(r.trigger for r in summary.relocalizations),
                            "position_error_m_median": float(np.median(errs)) if errs else None,
                            "position_error_m_max": float(np.max(errs)) if errs else None,
                            "rotation_error_deg_max": float(np.max(rots)) if rots else None},
        "tracking": s["tracking"],
        "errors": s["errors"],
    }


def _count(items):
    out: dict[str, int] = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return out


def run_synchronous(pool, scene_obj, n_frames, rate_hz, cfg, plane_map, planes_mode):
    """Baseline: one thread doing everything in turn (take the newest frame, extract, relocalize inline when due).

    The camera runs on its own clock as a real one does: frame ``i`` exists from ``t0 + i / rate_hz`` and a frame
    not taken before the next one arrives is lost (counted as dropped). Latency is from a frame's arrival to its
    plane set / pose, as for the threaded loop.
    """
    from reloc.live.factory import make_extractor, make_relocalizer

    extract = make_extractor(cfg, planes=planes_mode, scene=scene_obj)
    reloc = make_relocalizer(plane_map, cfg)
    for f in pool[:3]:
        reloc.locate(extract(f).planes)
    order = list(range(len(pool))) + list(range(len(pool) - 2, 0, -1))
    period_ns = int(round(1e9 / rate_hz))
    reloc_period_ns = int(cfg.live.reloc_period_s * 1e9)
    to_planes, to_pose = [], []
    processed = ok = 0
    last = -1
    next_reloc = None
    cpu0, t_start = time.process_time(), time.monotonic_ns()
    while True:
        now = time.monotonic_ns()
        i = (now - t_start) // period_ns  # the newest frame that has arrived
        if i >= n_frames:
            break
        if i <= last:
            time.sleep((t_start + (last + 1) * period_ns - now) / 1e9)
            continue
        last = i
        arrived = t_start + i * period_ns
        frame = pool[order[i % len(order)]]
        planes = extract(frame).planes
        processed += 1
        to_planes.append((time.monotonic_ns() - arrived) / 1e6)
        if next_reloc is None or time.monotonic_ns() >= next_reloc:
            r = reloc.locate(planes)
            next_reloc = time.monotonic_ns() + reloc_period_ns
            if r.status == "relocalized":
                ok += 1
                to_pose.append((time.monotonic_ns() - arrived) / 1e6)
    duration = (time.monotonic_ns() - t_start) / 1e9

    def pct(v):
        return None if not v else {"p50_ms": float(np.percentile(v, 50)), "p95_ms": float(np.percentile(v, 95)),
                                   "p99_ms": float(np.percentile(v, 99)), "max_ms": float(np.max(v)), "count": len(v)}

    return {
        "mode": "synchronous (baseline)", "rate": rate_hz, "frames_requested": n_frames, "duration_s": duration,
        "frames": {"captured": n_frames, "processed": processed, "dropped": n_frames - processed},
        "fps_processed": processed / duration, "capture_to_planes_ms": pct(to_planes),
        "capture_to_pose_ms": pct(to_pose),
        "cpu_s": time.process_time() - cpu0, "cpu_cores_busy": (time.process_time() - cpu0) / duration,
        "relocalizations": {"ok": ok},
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=10_000, help="Frames of the real-time run (default 10000).")
    ap.add_argument("--rate", type=float, default=30.0, help="Camera rate of the real-time run, Hz.")
    ap.add_argument("--fast-frames", type=int, default=600, help="Frames of the as-fast-as-possible run (0 = skip).")
    ap.add_argument("--sync-frames", type=int, default=1800,
                    help="Frames of the single-threaded baseline at --rate (0 = skip).")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=400)
    ap.add_argument("--pool", type=int, default=90, help="Pre-rendered frames (played forward and back).")
    ap.add_argument("--scene", default="living_room")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--planes", choices=["extract", "truth"], default="extract",
                    help="Plane extraction, or the simulator's ground-truth planes (Python, slow at 640x400).")
    ap.add_argument("--config", default=None, help="YAML config (defaults otherwise).")
    ap.add_argument("--out", default="live_loop", help="Results file stem under benchmarks/results.")
    args = ap.parse_args(argv)
    try:
        results_name(args.out, "--out")  # before the run, not after it
    except ValueError as e:
        ap.error(str(e))
    if args.frames < 1 or args.pool < 3:
        ap.error("--frames must be >= 1 and --pool >= 3")

    from reloc.config import config_as_dict, load_config
    from reloc.live.factory import load_plane_map, with_camera_noise

    cfg = load_config(args.config)
    map_planes, plane_map = load_plane_map(f"sim:{args.scene}")
    t0 = time.perf_counter()
    sim_src, pool = make_pool(args.scene, args.pool, args.width, args.height, args.seed, args.planes == "truth")
    print(f"pool: {len(pool)} frames {args.width}x{args.height} rendered in {time.perf_counter() - t0:.1f} s; "
          f"map: {len(map_planes)} planes", flush=True)
    cfg, note = with_camera_noise(cfg, sim_src)  # as reloc run does
    if note:
        print(note, flush=True)
    runs = []
    runs.append(run_once("realtime", pool, sim_src.scene, args.frames, float(args.rate), cfg, plane_map, map_planes,
                         args.planes, status_every=30))
    if args.sync_frames:
        runs.append(run_synchronous(pool, sim_src.scene, args.sync_frames, float(args.rate), cfg, plane_map,
                                    args.planes))
    if args.fast_frames:
        # A queue as long as the run: nothing is dropped, so frames per second is the loop's capacity.
        runs.append(run_once("fast", pool, sim_src.scene, args.fast_frames, "fast", cfg, plane_map, map_planes,
                             args.planes, status_every=0, queue_frames=args.fast_frames))

    def p(d, k):
        return None if d is None else d[k]

    rows = []
    for r in runs:
        f = r["frames"]
        rows.append([
            r["mode"], f["captured"], f["processed"], f["dropped"], r["fps_processed"],
            p(r["capture_to_planes_ms"], "p50_ms"), p(r["capture_to_planes_ms"], "p95_ms"),
            p(r["capture_to_planes_ms"], "p99_ms"), p(r["capture_to_pose_ms"], "p50_ms"),
            p(r["capture_to_pose_ms"], "p95_ms"), p(r["capture_to_pose_ms"], "p99_ms"),
            r["cpu_cores_busy"], *((r["rss_mb"]["start"], r["rss_mb"]["end"], 100 * r["rss_mb"]["growth_from_start"])
                                   if "rss_mb" in r else (None, None, None)),
        ])
    print_table(
        ["run", "captured", "processed", "dropped", "fps", "c->planes p50", "p95", "p99", "c->pose p50", "p95", "p99",
         "cores busy", "RSS start MB", "RSS end MB", "growth %"],
        rows, title=f"live loop, simulated {args.width}x{args.height} camera ({args.planes} planes)",
        floatfmt=[None, None, None, None, ".1f", ".1f", ".1f", ".1f", ".1f", ".1f", ".1f", ".2f", ".0f", ".0f", ".2f"],
    )
    for r in runs:
        if "extract_ms" not in r:
            continue
        rel = r["relocalizations"]
        print(f"{r['mode']}: extract p50 {p(r['extract_ms'], 'p50_ms')} ms, reloc p50 {p(r['reloc_ms'], 'p50_ms')} ms; "
              f"relocalizations {rel['ok']} ok / {rel['failed']} rejected, triggers {rel['triggers']}, "
              f"max position error {rel['position_error_m_max']} m; errors {r['errors'] or 'none'}")
    params = {**vars(args), "config": config_as_dict(cfg)}
    path = write_results(args.out, params=params, results={"runs": runs})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
