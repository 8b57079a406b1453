"""Accuracy of plane maps: every map plane against the simulator's surfaces, with extraction settings side by side.

    .venv/bin/python benchmarks/map_accuracy.py [--noise stereo,kinect,tof] [--scenes office,apartment] [--quick]

The maps are built as `reloc_accuracy.py` builds its suite's (same scenes, trajectories, resolution and seeds; Kinect
and ToF at 320x240, stereo at the OAK-D's 640x400), once per extraction setting, in the same process. Each map plane
is matched to the scene's true plane (normal within 10 deg) that its samples lie closest to (median distance), and
the table gives, over the map's area:

- the share of map area whose plane lies within 1 cm, 1-3, 3-6 cm and 6 cm or more of its surface (the median of
  its samples' distances), and the area-weighted mean of that distance;
- duplicates: planes of 0.5 m^2 or more that lie on the same true plane as a larger one and over the same place
  (a fifth of their samples within 15 cm of the other's, in the plane), which is what layers of one wall become;
- the area no true plane is within 10 deg of.

Settings: ``layers off`` (``layer_min_shared`` 0) and ``layers 0.5``; the default of each sensor is marked (0.5 for
the stereo camera, off for the others). Prints a table and writes benchmarks/results/map_accuracy.json (``--name``
for another stem) with the date, machine and commit. Kernels are warmed up before anything is timed.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

# _common first: it puts this checkout's root on sys.path before anything of the project is imported.
from _common import print_table, quick_presets, results_name, write_results  # noqa: E402

from reloc._numba import warm_up  # noqa: E402
from reloc.evaluation.suite import (  # noqa: E402
    SCENES, SUITE_MAP_TOUR, EvalSpec, build_scene_map, extraction_for_sensor, make_plane_source, suite_spec,
)
from reloc.extraction import ExtractionParams  # noqa: E402
from sim import KERNEL_MODULES as SIM_KERNELS  # noqa: E402
from sim.scenes import make_scene  # noqa: E402
from sim.trajectories import TOURS  # noqa: E402

BANDS_M = (0.01, 0.03, 0.06)
MATCH_ANGLE_RAD = np.radians(10.0)
DUPLICATE_MIN_AREA_M2 = 0.5
DUPLICATE_REACH_M = 0.15
DUPLICATE_MIN_SHARE = 0.2
SETTINGS = {"layers off": 0.0, "layers 0.5": 0.5}


def _overlap(a: np.ndarray, b: np.ndarray, normal: np.ndarray) -> float:
    """Share of the samples ``a`` within ``DUPLICATE_REACH_M`` of a sample of ``b``, in the plane of ``normal``."""
    a = a - np.outer(a @ normal, normal)
    b = b - np.outer(b @ normal, normal)
    near = 0
    for k in range(0, len(a), 256):  # in blocks: a wall of 20 m^2 has 2,000 samples
        d2 = ((a[k : k + 256, None, :] - b[None, :, :]) ** 2).sum(axis=2)
        near += int((d2.min(axis=1) <= DUPLICATE_REACH_M**2).sum())
    return near / len(a)


def map_errors(plane_map, scene) -> dict:
    """The figures of the module docstring for one map of ``scene``."""
    planes = plane_map.planes
    normals, offsets = np.asarray(scene.normals, np.float64), np.asarray(scene.offsets, np.float64)
    area_in = np.zeros(len(BANDS_M) + 1)
    unmatched = weighted = 0.0
    by_truth: dict[int, list] = {}
    n_planes = len(planes.normals)
    for i in range(n_planes):
        samples = np.asarray(planes.samples_of(i), np.float64)
        area = float(planes.areas[i])
        cand = np.flatnonzero(np.abs(normals @ planes.normals[i]) > np.cos(MATCH_ANGLE_RAD))
        if len(samples) == 0 or len(cand) == 0:
            unmatched += area
            continue
        med = np.median(np.abs(samples @ normals[cand].T + offsets[cand]), axis=0)
        j = int(np.argmin(med))
        area_in[int(np.searchsorted(BANDS_M, med[j], side="right"))] += area
        weighted += area * med[j]
        if area >= DUPLICATE_MIN_AREA_M2:
            by_truth.setdefault(int(cand[j]), []).append((area, samples))
    duplicates = 0
    for t, members in by_truth.items():
        members.sort(key=lambda m: -m[0])
        for k in range(1, len(members)):
            if any(_overlap(members[k][1], members[q][1], normals[t]) >= DUPLICATE_MIN_SHARE for q in range(k)):
                duplicates += 1
    matched = float(area_in.sum())
    return {"planes": n_planes, "area_m2": matched + unmatched, "matched_area_m2": matched,
            "area_by_offset_m2": area_in.tolist(), "unmatched_area_m2": unmatched,
            "mean_offset_m": weighted / matched if matched else float("nan"), "duplicates": duplicates}


def _spec(noise: str, scenes: tuple[str, ...], map_frames: int, map_seed: int, map_tour: str) -> EvalSpec:
    # The suite's maps, as reloc_accuracy.py and reloc eval build them (its queries are not used here).
    return suite_spec(noise, scenes=scenes, map_frames=map_frames, map_seed=map_seed, map_tour=map_tour)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", default="stereo,kinect,tof", help="Noise models (comma separated).")
    ap.add_argument("--scenes", default=",".join(SCENES), help="Scenes (comma separated).")
    ap.add_argument("--map-frames", type=int, default=3000, help="Frames per mapping trajectory.")
    ap.add_argument("--map-seed", type=int, default=EvalSpec.map_seed, help="Seed of the mapping trajectories.")
    ap.add_argument("--map-tour", choices=TOURS, default=SUITE_MAP_TOUR,
                    help="Where the mapping trajectories go: every room entered in turn (the suite's since "
                         "2026-11-29) or shortest paths to random places (the suite's before).")
    ap.add_argument("--quick", action="store_true", help="Two scenes, 600 frames per trajectory (a smoke run).")
    ap.add_argument("--name", default=None, help="Result file stem (default map_accuracy, map_accuracy_quick).")
    args = ap.parse_args()
    if args.quick:  # what the command line gives wins
        quick_presets(ap, args, {"scenes": ",".join(SCENES[:2]), "map_frames": 600})
    name = args.name or ("map_accuracy_quick" if args.quick else "map_accuracy")
    try:
        results_name(name)
    except ValueError as exc:
        ap.error(str(exc))
    noises = tuple(n.strip() for n in args.noise.split(",") if n.strip())
    bad = [n for n in noises if n not in ("stereo", "kinect", "tof")]
    if bad or not noises:
        ap.error(f"--noise: expected some of stereo, kinect, tof, got {args.noise!r}")
    scenes = tuple(s.strip() for s in args.scenes.split(",") if s.strip())
    if any(s not in SCENES for s in scenes) or not scenes:
        ap.error(f"--scenes: expected some of {', '.join(SCENES)}, got {args.scenes!r}")
    map_frames = args.map_frames
    if map_frames < 10:
        ap.error(f"--map-frames: expected at least 10, got {map_frames}")

    info = warm_up(("reloc.extraction.pipeline", "reloc.mapping._kernels", *SIM_KERNELS))
    print(f"warm-up: {info['kernels']} kernels in {info['seconds']:.1f} s ({info['cold']} compiled cold)")
    rows, results = [], {}
    for noise in noises:
        spec = _spec(noise, scenes, map_frames, args.map_seed, args.map_tour)
        shipped = extraction_for_sensor(spec, ExtractionParams())
        for label, share in SETTINGS.items():
            params = replace(shipped, layer_min_shared=share)
            default = params.layer_share == shipped.layer_share
            key = f"{noise}: {label}{' (default)' if default else ''}"
            per_scene, t0 = {}, time.perf_counter()
            for s in scenes:
                scene = make_scene(s)
                plane_map = build_scene_map(scene, spec, make_plane_source("extraction", scene, extraction=params))
                per_scene[s] = map_errors(plane_map, scene)
            seconds = time.perf_counter() - t0
            tot = {k: sum(r[k] for r in per_scene.values()) for k in ("planes", "area_m2", "matched_area_m2",
                                                                         "unmatched_area_m2", "duplicates")}
            by = np.sum([r["area_by_offset_m2"] for r in per_scene.values()], axis=0)
            mean = sum(r["mean_offset_m"] * r["matched_area_m2"] for r in per_scene.values()) / tot["matched_area_m2"]
            tot.update(area_by_offset_m2=by.tolist(), mean_offset_m=mean, seconds=seconds)
            results[key] = {"noise": noise, "layer_min_shared": share, "default": default, "all": tot,
                            "scenes": per_scene}
            share_of = by / tot["matched_area_m2"] * 100
            rows.append([key, tot["planes"], tot["area_m2"], *share_of, mean * 1e3, tot["duplicates"],
                         tot["unmatched_area_m2"], seconds])
            print(f"{key}: {tot['planes']} planes, {seconds:.0f} s", flush=True)
    print(f"\nmaps of {', '.join(scenes)} (map seed {args.map_seed}, tour {args.map_tour!r}, {map_frames} frames per "
          "trajectory)")
    print_table(["sensor: setting", "planes", "area m^2", "<1cm %", "1-3cm %", "3-6cm %", ">=6cm %",
                 "mean mm", "dupl.", "no truth m^2", "build s"], rows, floatfmt=".1f")
    params = {"noise": noises, "scenes": scenes, "map_frames": map_frames, "map_seed": args.map_seed,
              "map_tour": args.map_tour,
              "quick": args.quick, "settings": SETTINGS, "match_angle_deg": float(np.degrees(MATCH_ANGLE_RAD)),
              "bands_m": BANDS_M, "duplicate_min_area_m2": DUPLICATE_MIN_AREA_M2,
              "duplicate_reach_m": DUPLICATE_REACH_M, "duplicate_min_share": DUPLICATE_MIN_SHARE}
    print(f"wrote {write_results(name, params=params, results=results)}")


if __name__ == "__main__":
    main()
