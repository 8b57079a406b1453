"""Plane extraction latency: depth image to merged plane set, per stage, on simulated sequences.

    .venv/bin/python benchmarks/extraction_speed.py [--frames 240] [--threads 1] [--quick]

Frames: robot trajectories through four scenes (living_room, office, apartment, corridor), rendered before any
timing, at 640x480 (Kinect preset, Kinect noise) and 640x400 (OAK-D preset, stereo noise), full resolution, each
extracted with its sensor's noise law as `reloc run` would (before 2026-11-29 the OAK-D frames had the Kinect law).
Every configuration is warmed up (JIT and buffers) before it is timed; times come from ``ExtractionResult.timings_ms``
(``time.perf_counter`` around each stage), the wall time of the whole call and the thread's CPU time for it
(``time.thread_time``: on a shared machine the wall time also counts waiting for other processes; the load average
at the start and end is recorded). One numba thread by default
(``NUMBA_NUM_THREADS`` is set before numba is imported); ``--threads 2`` times the same kernels with two.

Configurations run side by side on the same frames: the defaults; without the point refinement (planes straight
from the merged voxel moments); a paper-like setting (no robust weights, no noise weights, no refinement: PCA
voxels, Eq. 2 weights, merging); without merging (VR-NM); and, for scale, every second pixel in both directions
(not full resolution, so not the figure the goal is about); and without the layer merge, which is on by default
for the stereo camera alone (``layer_min_shared`` 0; the same as the defaults for the Kinect frames).

``parallel=True`` on this machine's cores: ``--parallel-probe`` (run by the main run in a subprocess with two
numba threads) times the per-voxel moments and a per-point plane-distance pass, the two loop shapes of the
pipeline, compiled serially and with ``prange``, on the same frames.

Prints tables and writes benchmarks/results/extraction_speed.json (or ``--name``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

VARIANTS = {
    "default": {},
    "no-refine": {"refine_iterations": 0},
    "paper-like": {"refine_iterations": 0, "irls_iterations": 0, "noise_weights": False},
    "no-merge (VR-NM)": {"merge": False},
    "pixel stride 2": {"pixel_stride": 2},
    "no layers": {"layer_min_shared": 0.0},
}
DATASETS = (("kinect", "kinect"), ("oak-d", "stereo"))
SCENES = ("living_room", "office", "apartment", "corridor")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=240, help="Frames per camera (spread over the four scenes).")
    ap.add_argument("--threads", type=int, default=1, help="NUMBA_NUM_THREADS for this run.")
    ap.add_argument("--variants", default=",".join(VARIANTS), help="Comma-separated subset of: " + ", ".join(VARIANTS))
    ap.add_argument("--quick", action="store_true", help="40 frames per camera (a smoke run, not for reporting).")
    ap.add_argument("--name", default="extraction_speed", help="Result file stem in benchmarks/results/.")
    ap.add_argument("--parallel-probe", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.parallel_probe:
        os.environ["NUMBA_NUM_THREADS"] = "2"
        parallel_probe()
        return
    os.environ["NUMBA_NUM_THREADS"] = str(args.threads)  # before numba is imported (by reloc below)

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from _common import print_table, quick_presets, results_name, write_results

    try:
        results_name(args.name)  # before the simulator and numba are imported
    except ValueError as exc:
        ap.error(str(exc))
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        ap.error(f"--variants: unknown {unknown}; expected some of {list(VARIANTS)}")

    import numpy as np

    import sim
    from reloc._numba import warm_up
    from reloc.extraction import STAGES, ExtractionParams, PlaneExtractor
    from sim.cameras import resolve_intrinsics
    from sim.noise import make_noise

    if args.quick:  # what the command line gives wins
        quick_presets(ap, args, {"frames": 40})
    n_frames = args.frames
    info = warm_up(("reloc.extraction",))
    print(f"warm-up: {info['kernels']} kernels in {info['seconds']:.1f} s ({info['cold']} compiled cold); "
          f"numba threads: {args.threads}")

    load_start = os.getloadavg()
    per_scene = -(-n_frames // len(SCENES))
    datasets = {}
    for camera, noise in DATASETS:
        frames = []
        for scene in SCENES:
            frames += sim.simulate_frames(scene=scene, trajectory="robot", n_frames=per_scene, noise=noise,
                                          camera=camera, seed=1)
        datasets[(camera, noise)] = frames[:n_frames]

    rows, results = [], []
    for (camera, noise), frames in datasets.items():
        h, w = frames[0].depth_m.shape
        law = make_noise(noise).extraction_law(resolve_intrinsics(camera, w, h).fx)
        for name in variants:
            params = ExtractionParams(**VARIANTS[name])
            if law is not None:  # the sensor's own law, as reloc run takes it from the camera
                params = params.with_(noise_model=law[0], noise_coeff=law[1])
            ex = PlaneExtractor(params)
            for f in frames[:5]:  # warm-up: buffers sized, caches hot
                ex.extract(f)
            stage = {k: [] for k in (*STAGES, "total")}
            wall, cpu, n_planes, n_points = [], [], [], []
            for f in frames:
                c0 = time.thread_time()
                t0 = time.perf_counter()
                res = ex.extract(f)
                wall.append((time.perf_counter() - t0) * 1e3)
                cpu.append((time.thread_time() - c0) * 1e3)
                for k in stage:
                    stage[k].append(res.timings_ms.get(k, 0.0))
                n_planes.append(len(res.planes))
                n_points.append(res.stats["points"])
            wall = np.asarray(wall)
            cpu = np.asarray(cpu)
            med = {k: float(np.median(v)) for k, v in stage.items()}
            rec = {
                "camera": camera, "noise": noise, "width": w, "height": h, "variant": name, "params": VARIANTS[name],
                "noise_law": None if law is None else [law[0], float(law[1])],
                "frames": len(frames), "threads": args.threads,
                "wall_ms": {"median": float(np.median(wall)), "p95": float(np.percentile(wall, 95)),
                            "p99": float(np.percentile(wall, 99)), "mean": float(wall.mean())},
                "cpu_ms": {"median": float(np.median(cpu)), "p95": float(np.percentile(cpu, 95)),
                           "p99": float(np.percentile(cpu, 99))},
                "stage_median_ms": med,
                "stage_p95_ms": {k: float(np.percentile(v, 95)) for k, v in stage.items()},
                "planes_median": float(np.median(n_planes)), "points_median": float(np.median(n_points)),
            }
            results.append(rec)
            rows.append([f"{w}x{h} {name}", rec["wall_ms"]["median"], rec["wall_ms"]["p95"], rec["wall_ms"]["p99"],
                         rec["cpu_ms"]["median"], *[med[k] for k in STAGES], rec["planes_median"]])
    load_end = os.getloadavg()
    print_table(["frames / variant", "median", "p95", "p99", "cpu med", *STAGES, "planes"], rows,
                title=f"Extraction latency (ms per frame, {n_frames} frames per camera, {args.threads} thread(s); "
                      "stage columns are medians)",
                floatfmt=["s"] + [".2f"] * (4 + len(STAGES)) + [".0f"])
    print(f"load average (1, 5, 15 min) at the start {load_start}, at the end {load_end} on {os.cpu_count()} cores: "
          "wall times include waiting for other processes; 'cpu med' is this thread's CPU time (time.thread_time), "
          "which does not (shared caches and cores still slow it)")
    probe = _run_parallel_probe()
    if probe is not None:
        print_table(["loop (640x480 frames)", "serial ms", "prange 2 threads ms", "speed-up"],
                    [[r["kernel"], r["serial_ms"], r["parallel_ms"], r["serial_ms"] / r["parallel_ms"]]
                     for r in probe], title="parallel=True on two cores (median per frame)",
                    floatfmt=["s", ".3f", ".3f", ".2f"])
    path = write_results(args.name, params={"frames_per_camera": n_frames, "threads": args.threads,
                                            "scenes": SCENES, "datasets": DATASETS, "variants": variants},
                         results={"latency": results, "parallel_probe": probe,
                                  "load_average": {"start": load_start, "end": load_end}})
    print(f"wrote {path}")


def _run_parallel_probe():
    """Run :func:`parallel_probe` in a subprocess (two numba threads); its JSON result, or None if it failed."""
    import json
    import subprocess

    out = subprocess.run([sys.executable, os.path.abspath(__file__), "--parallel-probe"], capture_output=True,
                         text=True, timeout=900)
    if out.returncode != 0:
        print(f"parallel probe failed:\n{out.stderr[-2000:]}", file=sys.stderr)
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def parallel_probe() -> None:
    """Serial vs prange versions of the pipeline's two loop shapes on real frames; prints one JSON line.

    The probe compiles its own kernels (the one place outside the kernel modules that imports numba): each loop is
    written once with ``prange``, which is a plain ``range`` when compiled without ``parallel=True``.
    """
    import json

    import numba
    import numpy as np

    import sim
    from reloc.extraction.backproject import depth_to_points
    from reloc.extraction.voxelize import voxelize

    def moments(sorted_pts, voxel_start, nv, out):
        for v in numba.prange(nv):
            a = voxel_start[v]
            b = voxel_start[v + 1]
            rx = np.float64(sorted_pts[a, 0])
            ry = np.float64(sorted_pts[a, 1])
            rz = np.float64(sorted_pts[a, 2])
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
            for j in range(a, b):
                x = sorted_pts[j, 0] - rx
                y = sorted_pts[j, 1] - ry
                z = sorted_pts[j, 2] - rz
                s0 += x
                s1 += y
                s2 += z
                s3 += x * x
                s4 += x * y
                s5 += x * z
                s6 += y * y
                s7 += y * z
                s8 += z * z
            out[v, 0] = s0 + s1 + s2
            out[v, 1] = s3 + s4 + s5 + s6 + s7 + s8

    def distances(sorted_pts, voxel_start, nv, plane, band, labels):
        for v in numba.prange(nv):
            for j in range(voxel_start[v], voxel_start[v + 1]):
                r = (plane[0] * sorted_pts[j, 0] + plane[1] * sorted_pts[j, 1] + plane[2] * sorted_pts[j, 2]
                     + plane[3])
                labels[j] = 0 if abs(r) < band * sorted_pts[j, 2] ** 2 else -1

    opts = {"fastmath": {"reassoc", "contract"}, "error_model": "numpy"}
    kernels = {name: (numba.njit(**opts)(fn), numba.njit(parallel=True, **opts)(fn))
               for name, fn in (("voxel moments", moments), ("point-plane distances", distances))}
    frames = sim.simulate_frames(scene="office", trajectory="robot", n_frames=30, noise="kinect", camera="kinect",
                                 seed=1)
    grids = []
    for f in frames:
        pts, _ = depth_to_points(f.depth_m, f.intrinsics)
        g = voxelize(pts.copy())
        grids.append((g.points.copy(), g.start.copy(), len(g)))
    results = []
    for name, (ser, par) in kernels.items():
        times = {"serial": [], "parallel": []}
        for mode, fn in (("serial", ser), ("parallel", par)):
            for rep in range(3):
                for pts, start, nv in grids:
                    if name == "voxel moments":
                        args = (pts, start, nv, np.zeros((nv, 2)))
                    else:
                        args = (pts, start, nv, np.array([0.0, 0.0, -1.0, 2.0]), 5e-3, np.empty(len(pts), np.int32))
                    t0 = time.perf_counter()
                    fn(*args)
                    if rep:  # the first round compiles and warms up
                        times[mode].append((time.perf_counter() - t0) * 1e3)
        results.append({"kernel": name, "serial_ms": float(np.median(times["serial"])),
                        "parallel_ms": float(np.median(times["parallel"])), "threads": numba.get_num_threads()})
    print(json.dumps(results))


if __name__ == "__main__":
    main()
