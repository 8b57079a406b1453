"""Speed of the simulated camera: render time per frame for every scene and camera preset, the noise models, the
slow NumPy reference renderer side by side, frames per second for writing a sequence to disk, and the ground-truth
planes of a frame (the plane source of every oracle suite) beside the same with ``np.unique(axis=0)``.

    .venv/bin/python benchmarks/sim_speed.py [--frames 30] [--write-frames 100]

Prints a table and writes benchmarks/results/sim_speed.json (``--name`` for another stem) with the date, machine
and commit. Kernels are warmed up before anything is timed.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

# _common first: it puts this checkout's root on sys.path before anything of the project is imported.
from _common import results_name, write_results  # noqa: E402

from reloc._numba import warm_up  # noqa: E402
from sim import KERNEL_MODULES as SIM_KERNELS, make_camera  # noqa: E402
import sim.ground_truth as ground_truth  # noqa: E402
from sim.cameras import PRESETS, preset  # noqa: E402
from sim.noise import NOISE_NAMES, make_noise  # noqa: E402
from sim.reference import reference_render  # noqa: E402
from sim.render import render  # noqa: E402
from sim.scenes import SCENE_NAMES, make_scene  # noqa: E402
from sim.trajectories import random_views  # noqa: E402
from sim.writer import write_sequence  # noqa: E402


def _stats(times_s: list[float]) -> dict:
    ms = np.asarray(times_s) * 1e3
    return {"median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)), "n": int(len(ms))}


def _unique_rows_count(rows: np.ndarray) -> int:
    return len(np.unique(rows, axis=0))


def _unique_rows_first(rows: np.ndarray) -> np.ndarray:
    return np.unique(rows, axis=0, return_index=True)[1]


def _ground_truth_planes(n_frames: int) -> list[dict]:
    """``visible_planes`` of Kinect frames at 320x240 (the suite's), ours and with the distinct grid rows found by
    ``np.unique(axis=0)`` (before 773cddf); the two must give the same arrays."""
    print(f"\n{'ground-truth planes':<30}{'scene':<15}{'frames':>7}{'planes':>8}{'median ms':>11}{'p95 ms':>9}")
    out = []
    for scene_name in ("office", "meeting_rooms"):
        camera = make_camera(scene_name, "handheld", n_frames, "kinect", "kinect", seed=0, width=320, height=240)
        scene, frames = camera.scene, list(camera)
        sets = {}
        for label, count, first in (("ours (reloc.rowkeys)", ground_truth.count_unique_rows,
                                      ground_truth.first_unique_rows),
                                     ("np.unique(axis=0)", _unique_rows_count, _unique_rows_first)):
            saved = ground_truth.count_unique_rows, ground_truth.first_unique_rows
            ground_truth.count_unique_rows, ground_truth.first_unique_rows = count, first
            try:
                ground_truth.visible_planes(frames[0], scene)
                times, sets[label] = [], []
                for f in frames:
                    t0 = time.perf_counter()
                    ps = ground_truth.visible_planes(f, scene)
                    times.append(time.perf_counter() - t0)
                    sets[label].append(ps)
            finally:
                ground_truth.count_unique_rows, ground_truth.first_unique_rows = saved
            s = _stats(times)
            planes = int(sum(len(ps) for ps in sets[label]))
            out.append({"method": label, "scene": scene_name, "planes": planes, **s})
            print(f"{label:<30}{scene_name:<15}{len(frames):>7}{planes:>8}{s['median_ms']:>11.2f}{s['p95_ms']:>9.2f}")
        a, b = sets.values()
        same = all(np.array_equal(getattr(x, f), getattr(y, f)) for x, y in zip(a, b)
                   for f in ("areas", "sample_points", "sample_ptr", "covariances", "centroids"))
        out[-2]["same_arrays"] = out[-1]["same_arrays"] = bool(same)
        print(f"{'':<30}{scene_name:<15}  the same arrays both ways: {same}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="Viewpoints timed per scene and camera.")
    ap.add_argument("--write-frames", type=int, default=100, help="Frames of the sequence-writing run.")
    ap.add_argument("--name", default="sim_speed", help="Result file stem in benchmarks/results/.")
    args = ap.parse_args()
    try:
        results_name(args.name)
    except ValueError as exc:
        ap.error(str(exc))

    info = warm_up(SIM_KERNELS)
    rows = []
    print(f"warm-up: {info['kernels']} kernels in {info['seconds']:.1f} s ({info['cold']} compiled cold)")
    print(f"\n{'scene':<15}{'planes':>7}{'polys':>7}  {'camera':<9}{'size':>10}{'median ms':>11}{'p95 ms':>9}")
    for name in SCENE_NAMES:
        scene = make_scene(name)
        poses = random_views(scene, args.frames, seed=0)
        for cam in PRESETS:
            intr = preset(cam)
            render(scene, intr, poses[0])
            times = []
            for T in poses:
                t0 = time.perf_counter()
                render(scene, intr, T)
                times.append(time.perf_counter() - t0)
            s = _stats(times)
            rows.append({"scene": name, "planes": scene.n_planes, "polygons": scene.n_polygons, "camera": cam,
                         "width": intr.width, "height": intr.height, "renderer": "numba", **s})
            print(f"{name:<15}{scene.n_planes:>7}{scene.n_polygons:>7}  {cam:<9}{intr.width:>5}x{intr.height:<4}"
                  f"{s['median_ms']:>11.2f}{s['p95_ms']:>9.2f}")

    # Baseline: the NumPy reference renderer on the same views (small image, it is slow).
    print(f"\n{'renderer':<22}{'scene':<14}{'size':>9}{'median ms':>11}{'p95 ms':>9}")
    baseline = []
    for name in ("living_room", "apartment"):
        scene = make_scene(name)
        intr = preset("kinect").scaled(160, 120)
        poses = random_views(scene, 5, seed=1)
        for label, fn in (("numba (sim.render)", render), ("numpy reference", reference_render)):
            fn(scene, intr, poses[0])
            times = []
            for T in poses:
                t0 = time.perf_counter()
                fn(scene, intr, T)
                times.append(time.perf_counter() - t0)
            s = _stats(times)
            baseline.append({"renderer": label, "scene": name, "width": 160, "height": 120, **s})
            print(f"{label:<22}{name:<14}{'160x120':>9}{s['median_ms']:>11.2f}{s['p95_ms']:>9.2f}")

    # Noise models on a 640x480 apartment frame.
    print(f"\n{'noise':<10}{'median ms':>11}{'p95 ms':>9}   (640x480, apartment)")
    scene = make_scene("apartment")
    intr = preset("kinect")
    poses = random_views(scene, args.frames, seed=2)
    truths = [render(scene, intr, T) for T in poses]
    noise_rows = []
    for nm in NOISE_NAMES:
        model = make_noise(nm)
        model.apply(*truths[0], intr, np.random.default_rng(0))
        times = []
        for i, (d, lab) in enumerate(truths):
            rng = np.random.default_rng(i)
            t0 = time.perf_counter()
            model.apply(d, lab, intr, rng)
            times.append(time.perf_counter() - t0)
        s = _stats(times)
        noise_rows.append({"noise": nm, **s})
        print(f"{nm:<10}{s['median_ms']:>11.2f}{s['p95_ms']:>9.2f}")

    # Whole pipeline: render + noise + PNG writing of a robot sequence.
    print(f"\n{'sequence written':<40}{'frames':>7}{'seconds':>9}{'frames/s':>10}")
    write_rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene_name, cam in (("apartment", "kinect"), ("apartment", "oak-d"), ("building", "kinect")):
            c = make_camera(scene_name, "robot", args.write_frames, "kinect", cam, seed=0)
            t0 = time.perf_counter()
            s = write_sequence(iter(c), c.scene, Path(tmp) / f"{scene_name}_{cam}")
            dt = time.perf_counter() - t0
            write_rows.append({"scene": scene_name, "camera": cam, "frames": s.n_frames, "seconds": dt,
                               "frames_per_s": s.n_frames / dt})
            label = f"{scene_name}, {cam}, kinect noise, robot"
            print(f"{label:<40}{s.n_frames:>7}{dt:>9.2f}{s.n_frames / dt:>10.1f}")

    gt_rows = _ground_truth_planes(args.frames)

    path = write_results(
        args.name, params={"frames": args.frames, "write_frames": args.write_frames},
        results={"render": rows, "render_baseline": baseline, "noise": noise_rows, "write_sequence": write_rows,
                 "ground_truth_planes": gt_rows},
    )
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
