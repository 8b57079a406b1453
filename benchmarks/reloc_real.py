"""Relocalization on the real clips of ../shared/data/real/ (TUM RGB-D Kinect v1, ICL-NUIM): what they allow.

The clips are short (1.2-1.6 s of TUM, 5 ICL-NUIM frames), so each map is built from the first part of a clip and
queried with its later frames, which see the same surfaces from a few centimetres away; the frames of the other
clips are the negatives. Cases (``CASES``):

- ``tum_fr2_desk``: map from frames 0-24, queries 25-49 every third frame. The clip has no IMU: the rows ``imu``
  take each frame's gravity from the motion-capture world's -z (a stand-in for an IMU; the mocap world's z is up
  within a few degrees, see ``drivers.readers``), the rows ``camera_y`` use the extraction's fallback (the camera's
  y axis with the tilt tolerance of the config; this camera looks down at the desk by ~26 deg, beyond it).
- ``tum_fr1_xyz``: map from frames 0-19, queries 20-36 every second frame, gravity from the clip's accelerometer.
- ``icl_nuim_living_room``: each of the 5 noise-free frames against the map of the other four (leave one out).

Mapping for clips this short: a keyframe every 2 cm or 2 deg, planes seen in 2 keyframes kept (1 for ICL-NUIM,
whose 5 frames look at different parts of the room). Submaps of ``--windows`` frames (TUM; mocap as odometry).
Methods side by side on the same maps and submaps: ours (the shipped matcher) and the paper's decision rules
(``reloc_accuracy.paper_settings``). Counting as in ``reloc.evaluation.metrics`` (TP within 0.25 m and 5 deg of the
mocap pose). For each positive the submap is also verified at its mocap pose: the number of distinct map planes it
matches there says whether the map and the view hold the 5 distinct surfaces scene uniqueness asks for, and
whether the mocap pose is confirmed (``Relocalizer.confirm``: the pose ``locate`` would accept were it its only
hypothesis) says whether the query is identifiable at all under ours' acceptance rules.

``python benchmarks/reloc_real.py [--windows 1,10] [--set KEY=VALUE] [--variant KEY=VALUE[,...]] [--name reloc_real]``
(``--set``, repeatable: an ExtractionParams setting for every clip; ``--variant``, repeatable: matcher settings
evaluated as one more method beside ours, as in ``reloc_accuracy.py``); the folder is ``$RELOC_REAL_DATA`` or
``../shared/data/real`` beside the repository.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import REPO_ROOT, parse_overrides, print_table, results_name, write_results  # noqa: E402

import numpy as np  # noqa: E402

WORLD_DOWN = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class Case:
    """A map from ``map_frames`` of ``clip`` and positive queries at ``query_frames`` (leave-one-out: each frame
    against the map of the others)."""

    name: str
    clip: str
    map_frames: tuple[int, int] | None
    query_frames: tuple[int, ...]
    gravity: str  # "imu" (the clip's own, or the mocap world's -z), "camera_y" (the extraction's fallback)
    min_observations: int
    windows: bool = True  # TUM clips: windowed submaps with mocap odometry; ICL-NUIM: single frames
    leave_one_out: bool = False


CASES = (
    Case("fr2_desk/imu", "tum_fr2_desk", (0, 25), tuple(range(25, 50, 3)), "imu", 2),
    Case("fr2_desk/camera_y", "tum_fr2_desk", (0, 25), tuple(range(25, 50, 3)), "camera_y", 2),
    Case("fr1_xyz/imu", "tum_fr1_xyz", (0, 20), tuple(range(20, 37, 2)), "imu", 2),
    Case("icl_nuim/leave_one_out", "icl_nuim_living_room", None, tuple(range(5)), "imu", 1, windows=False,
         leave_one_out=True),
)


def real_data_dir() -> Path:
    return Path(os.environ.get("RELOC_REAL_DATA", REPO_ROOT.parent / "shared" / "data" / "real"))


def with_gravity(frame, mode: str):
    """``frame`` with the gravity of ``mode``: "imu" keeps the clip's own (accelerometer) and otherwise takes the
    mocap world's -z in the camera frame; "camera_y" drops it (the extraction's fallback decides)."""
    if mode == "camera_y":
        return replace(frame, gravity_cam=None)
    if frame.gravity_cam is not None or frame.T_world_cam is None:
        return frame
    return replace(frame, gravity_cam=frame.T_world_cam[:3, :3].T @ WORLD_DOWN)


def mapping_params(case: Case):
    from reloc.mapping import MappingParams

    return MappingParams(keyframe_min_translation_m=0.02, keyframe_min_rotation_rad=math.radians(2.0),
                         min_observations=case.min_observations)


class Clip:
    """A clip's frames (gravity per ``Case.gravity``) and their plane sets, extracted once."""

    def __init__(self, root: Path, clip: str, gravity: str, extraction=None):
        from drivers.readers import open_sequence
        from reloc.extraction import PlaneExtractor

        self.seq = open_sequence(root / clip)
        self.gravity = gravity
        self.extractor = PlaneExtractor(extraction)
        self._planes: dict[int, object] = {}

    def frame(self, i: int):
        return with_gravity(self.seq[i], self.gravity)

    def planes(self, i: int):
        if i not in self._planes:
            self._planes[i] = self.extractor.extract(self.frame(i)).planes
        return self._planes[i]

    def submap(self, q: int, window: int, params):
        from reloc.mapping import build_submap

        idx = [i for i in range(q - window + 1, q + 1) if i >= 0]
        if len(idx) == 1:
            return build_submap([self.planes(q)])
        return build_submap([self.planes(i) for i in idx], [self.seq.T_world_cam[i] for i in idx], params)


def build_case_map(clip: Clip, frames, params):
    """The map of ``frames`` (indices) of ``clip``, with the planes the clip's queries use (extracted once)."""
    from reloc.mapping import build_map

    index = {int(clip.seq.stamps_ns[i]): i for i in frames}
    return build_map((clip.frame(i) for i in frames), lambda f: clip.planes(index[int(f.stamp_ns)]), params)


def matched_at_truth(reloc, submap, T_map_cam) -> int:
    """Distinct map planes the submap matches at the pose ``T_map_cam`` (verification without the triplet)."""
    if len(submap) == 0:
        return 0
    used, _, vs_ptr, vs_pts = reloc.prepare(submap)
    v = reloc.verify(used, vs_ptr, vs_pts, T_map_cam[None, :3, :3].copy(), T_map_cam[None, :3, 3].copy(),
                     np.array([[0, 1, 2, -1, -1, -1]], np.int32), require_triplet=False)
    return int(v.n_matched[0])


def run(root: Path, windows=(1, 10), extraction=None, cases=CASES, variants=None) -> dict:
    """Every case, window and method: per-query records and TP / TN / FP / FN per (case, window, method); planes
    extracted with ``extraction`` (ExtractionParams, None = the defaults). ``variants``: more methods, name ->
    MatchingParams, on the same maps and submaps."""
    from reloc._numba import warm_up
    from reloc.evaluation.metrics import classify, identifiable
    from reloc.matching import MatchingParams, Relocalizer
    from reloc.transforms import pose_error
    from reloc_accuracy import paper_settings

    warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline"))
    ours = MatchingParams()
    methods = {"ours": ours, "paper settings": paper_settings(ours), **(variants or {})}
    clips: dict[tuple[str, str], Clip] = {}

    def clip_of(name: str, gravity: str) -> Clip:
        if (name, gravity) not in clips:
            clips[(name, gravity)] = Clip(root, name, gravity, extraction)
        return clips[(name, gravity)]

    # Maps: one per case, or one per left-out frame.
    maps: dict[tuple[str, int], object] = {}
    map_info = {}
    for case in cases:
        clip = clip_of(case.clip, case.gravity)
        params = mapping_params(case)
        if case.leave_one_out:
            for q in case.query_frames:
                others = [i for i in range(len(clip.seq)) if i != q]
                maps[(case.name, q)] = build_case_map(clip, others, params)
        else:
            m = build_case_map(clip, range(*case.map_frames), params)
            for q in case.query_frames:
                maps[(case.name, q)] = m
        sizes = sorted({len(maps[(case.name, q)]) for q in case.query_frames})
        map_info[case.name] = {"planes": sizes, "frames": case.map_frames or "all but the query"}
    # One relocalizer per map and method (a case's queries share its map, except when left out in turn).
    by_map, relocs = {}, {}
    for key, m in maps.items():
        if id(m) not in by_map:
            by_map[id(m)] = {name: Relocalizer(m, p) for name, p in methods.items()}
        relocs[key] = by_map[id(m)]
    windowed = {c.clip: c.windows for c in cases}
    # Negatives: the other clips' queries (single frames and windows alike) against each case's (first) map.
    records = []
    for case in cases:
        params = mapping_params(case)
        for window in windows if case.windows else (1,):
            jobs = [(case.clip, q, True, (case.name, q)) for q in case.query_frames]
            first = (case.name, case.query_frames[0])
            for other in cases:
                if other.clip == case.clip:
                    continue
                jobs += [(other.clip, q, False, first) for q in other.query_frames]
            for clip_name, q, positive, map_key in jobs:
                src = clip_of(clip_name, case.gravity if clip_name == case.clip else "imu")
                submap = src.submap(q, window if windowed[clip_name] else 1, params)
                truth = src.seq.T_world_cam[q]
                for method, reloc in relocs[map_key].items():
                    t0 = time.perf_counter()
                    res = reloc.locate(submap)
                    ms = (time.perf_counter() - t0) * 1e3
                    errors = pose_error(res.T_map_cam, truth) if (positive and res.relocalized) else None
                    rec = {
                        "case": case.name, "window": window, "method": method, "query": f"{clip_name}/{q}",
                        "positive": positive, "submap_planes": len(submap), "status": res.status,
                        "reason": res.reason, "label": classify(positive, False, res.relocalized, errors),
                        "translation_error_m": None if errors is None else errors[0],
                        "rotation_error_deg": None if errors is None else errors[1], "ms": ms,
                    }
                    if positive and method == "ours":
                        rec["matched_at_truth"] = matched_at_truth(reloc, submap, truth)
                        rec["identifiable"], rec["identifiable_reason"] = identifiable(reloc, submap, truth)
                    records.append(rec)
    rows = {}
    for r in records:
        key = (r["case"], r["window"], r["method"])
        row = rows.setdefault(key, {"TP": 0, "TN": 0, "FP": 0, "FN": 0, "matched_at_truth": [], "errors_m": [],
                                    "ms": [], "identifiable": 0})
        row[r["label"]] += 1
        row["ms"].append(r["ms"])
        if "matched_at_truth" in r:
            row["matched_at_truth"].append(r["matched_at_truth"])
            row["identifiable"] += int(r["identifiable"])
        if r["translation_error_m"] is not None and r["label"] == "TP":
            row["errors_m"].append(r["translation_error_m"])
    return {"maps": map_info, "rows": [{"case": k[0], "window": k[1], "method": k[2], **v} for k, v in rows.items()],
            "queries": records}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--windows", default="1,10", help="Submap windows (frames) for the TUM clips, comma-separated.")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="ExtractionParams override for every clip (repeatable), to measure a candidate setting")
    ap.add_argument("--variant", action="append", default=[], metavar="KEY=VALUE[,KEY=VALUE...]",
                    help="MatchingParams settings evaluated as one more method beside ours (repeatable)")
    ap.add_argument("--name", default="reloc_real", help="Results file stem under benchmarks/results.")
    args = ap.parse_args()
    try:
        name = results_name(args.name)
        from reloc.extraction import ExtractionParams
        from reloc.matching import MatchingParams
        from reloc_accuracy import parse_variant

        extraction = ExtractionParams().with_(**parse_overrides(args.set)) if args.set else None
        variants = {f"ours with {spec}": parse_variant(spec, MatchingParams()) for spec in args.variant}
    except ValueError as exc:
        ap.error(str(exc))
    windows = tuple(int(w) for w in args.windows.split(","))
    root = real_data_dir()
    if not root.is_dir():
        print(f"real depth clips not found at {root} (set RELOC_REAL_DATA to their folder)", file=sys.stderr)
        return 2
    t0 = time.time()
    res = run(root, windows, extraction, variants=variants)
    head = ["case", "window", "method", "TP", "TN", "FP", "FN", "median error", "matched at mocap pose",
            "identifiable", "median ms"]
    table = []
    for r in res["rows"]:
        mt = r["matched_at_truth"]
        table.append([
            r["case"], r["window"], r["method"], r["TP"], r["TN"], r["FP"], r["FN"],
            f"{1e3 * float(np.median(r['errors_m'])):.1f} mm" if r["errors_m"] else "-",
            f"{min(mt)}-{max(mt)} (median {float(np.median(mt)):g})" if mt else "",
            f"{r['identifiable']} of {len(mt)}" if mt else "",
            f"{float(np.median(r['ms'])):.1f}",
        ])
    print_table(head, table, title="Real clips: positives from the mapped clip, negatives from the others")
    for case, info in res["maps"].items():
        print(f"map {case}: {info['planes']} planes from frames {info['frames']}")
    path = write_results(name, params={"windows": list(windows), "data": str(root),
                                       "cases": [asdict(c) for c in CASES], "set": args.set,
                                       "variant": args.variant}, results=res)
    print(f"{time.time() - t0:.0f} s; wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
