"""Plane extraction latency: depth image to merged plane set, per stage, on simulated sequences.

    .venv/bin/python benchmarks/extraction_speed.py [--frames 240] [--threads 1] [--quick]

Frames: robot trajectories through four scenes (living_room, office, apartment, corridor), rendered before any
timing, at 640x480 (Kinect preset, Kinect noise) and 640x400 (OAK-D preset, stereo noise), full resolution. Every
configuration is warmed up (JIT and buffers) before it is timed; times come from ``ExtractionResult.timings_ms``
(``time.perf_counter`` around each stage) and the wall time of the whole call. One numba thread by default
(``NUMBA_NUM_THREADS`` is set before numba is imported); ``--threads 2`` times the same kernels with two.

Configurations run side by side on the same frames: the defaults; without the point refinement (planes straight
from the merged voxel moments); a paper-like setting (no robust weights, no noise weights, no refinement: PCA
voxels, Eq. 2 weights, merging); and without merging (VR-NM).

Prints a table and writes benchmarks/results/extraction_speed.json (or ``--name``).
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
    args = ap.parse_args()
    os.environ["NUMBA_NUM_THREADS"] = str(args.threads)  # before numba is imported (by reloc below)

    import numpy as np

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import sim
    from _common import print_table, write_results

    from reloc._numba import warm_up
    from reloc.extraction import STAGES, ExtractionParams, PlaneExtractor

    n_frames = 40 if args.quick else args.frames
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        ap.error(f"--variants: unknown {unknown}; expected some of {list(VARIANTS)}")
    info = warm_up(("reloc.extraction",))
    print(f"warm-up: {info['kernels']} kernels in {info['seconds']:.1f} s ({info['cold']} compiled cold); "
          f"numba threads: {args.threads}")

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
        for name in variants:
            params = ExtractionParams(**VARIANTS[name])
            ex = PlaneExtractor(params)
            for f in frames[:5]:  # warm-up: buffers sized, caches hot
                ex.extract(f)
            stage = {k: [] for k in (*STAGES, "total")}
            wall, n_planes, n_points = [], [], []
            for f in frames:
                t0 = time.perf_counter()
                res = ex.extract(f)
                wall.append((time.perf_counter() - t0) * 1e3)
                for k in stage:
                    stage[k].append(res.timings_ms.get(k, 0.0))
                n_planes.append(len(res.planes))
                n_points.append(res.stats["points"])
            wall = np.asarray(wall)
            med = {k: float(np.median(v)) for k, v in stage.items()}
            rec = {
                "camera": camera, "noise": noise, "width": w, "height": h, "variant": name, "params": VARIANTS[name],
                "frames": len(frames), "threads": args.threads,
                "wall_ms": {"median": float(np.median(wall)), "p95": float(np.percentile(wall, 95)),
                            "p99": float(np.percentile(wall, 99)), "mean": float(wall.mean())},
                "stage_median_ms": med,
                "stage_p95_ms": {k: float(np.percentile(v, 95)) for k, v in stage.items()},
                "planes_median": float(np.median(n_planes)), "points_median": float(np.median(n_points)),
            }
            results.append(rec)
            rows.append([f"{w}x{h} {name}", rec["wall_ms"]["median"], rec["wall_ms"]["p95"], rec["wall_ms"]["p99"],
                         *[med[k] for k in STAGES], rec["planes_median"]])
    print_table(["frames / variant", "median", "p95", "p99", *STAGES, "planes"], rows,
                title=f"Extraction latency (ms per frame, {n_frames} frames per camera, {args.threads} thread(s); "
                      "stage columns are medians)",
                floatfmt=["s"] + [".2f"] * (3 + len(STAGES)) + [".0f"])
    path = write_results(args.name, params={"frames_per_camera": n_frames, "threads": args.threads,
                                            "scenes": SCENES, "datasets": DATASETS, "variants": variants},
                         results=results)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
