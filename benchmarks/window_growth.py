"""What a longer history would give the views the matcher turns away as ambiguous, measured on saved suites.

Every query of a suite saved with ``reloc_accuracy.py --save-prepared`` (its positives and negatives in each scene's
map) is relocalized as the suite does. Each one rejected as ambiguous then grows its window back in time, ``--step``
frames at a time up to ``--most`` frames (as far as its trajectory goes), and is matched again at every size: the
frames before it may have seen what tells its place from a twin (the next meeting room, the corridor turned round).
A rule takes the first answer, over the sizes in order, whose ambiguity ratio (its score over the best at another
pose) is at least ``--min-ratio``: 1.55 is the decision's own, so any answer; larger values ask more of an answer
found after growing, to offset the extra tries; ``inf`` takes only an answer with no rival left. A grown query
takes the ambiguity label of the frames it ends with (:func:`reloc.evaluation.ambiguity.is_ambiguous`), so a view
ambiguous in its first frames may become one with an answer, and the other way round.

Another rule grows a query only when none of the poses its first decision had to choose between (rival scores
within the decision's ratio of the best) is one of the map's own repeats: the share of the map's vertical planes
within ``REPEAT_RADIUS_M`` of the best pose's camera (by area) that the move from the best pose to the rival lays onto
a map plane (:func:`repeat_share`) must stay under ``--max-repeat-share``. Twin rooms are repeats; a view that only
looks like another corner of a room that does not repeat is not.

Ours (no growth) and each rule are printed side by side with TP, TN, FP, FN and the recall, and what changed: the
queries each rule answers that ours rejects, right or wrong. The matcher is the one of this checkout, with its
defaults; the grown windows' older frames are rendered and their planes extracted here (seeded, so a rerun gives the
same figures).

    python benchmarks/window_growth.py --prepared DIR [--prepared DIR2 ...] [--most 120] [--step 20]
        [--min-ratio 1.55,3,inf] [--max-repeat-share 0.3,0.5]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, results_name, write_results  # noqa: E402

REPEAT_RADIUS_M = 4.0  # map planes this close to the best pose's camera (horizontally) are laid onto the map
REPEAT_ANGLE_DEG = 10.0  # a counterpart faces within this of the moved plane
REPEAT_OFFSET_M = 0.05  # and the moved plane's samples lie this close to its plane (median)
REPEAT_SAMPLE_M = 0.15  # and half of them this close to one of its samples


def repeat_share(planes, T_best: np.ndarray, T_rival: np.ndarray) -> float:
    """The share (by area) of the map's vertical planes within ``REPEAT_RADIUS_M`` of ``T_best``'s camera that the
    move ``T_rival inv(T_best)`` lays onto a map plane: about 1 when the rival is a twin of the best (the next
    meeting room), low for a rival at a place the map does not repeat. A wall slid along itself counts as laid (a
    move along a corridor lays its walls). 0 when no such plane is near."""
    from reloc.transforms import invert

    S = T_rival @ invert(T_best)
    R, t = S[:3, :3], S[:3, 3]
    n = planes.normals
    near = (np.abs(n[:, 2]) < 0.5) & (np.linalg.norm(planes.centroids[:, :2] - T_best[:2, 3], axis=1)
                                      < REPEAT_RADIUS_M)
    total = laid = 0.0
    for i in np.flatnonzero(near):
        pts = np.asarray(planes.samples_of(i), dtype=np.float64)
        pts = pts[:: max(1, len(pts) // 20)] @ R.T + t
        total += planes.areas[i]
        for k in np.flatnonzero(n @ (R @ n[i]) >= np.cos(np.radians(REPEAT_ANGLE_DEG))):
            if np.median(np.abs(pts @ n[k] + planes.offsets[k])) > REPEAT_OFFSET_M:
                continue
            theirs = np.asarray(planes.samples_of(k), dtype=np.float64)
            nearest = np.min(np.linalg.norm(theirs[None, :, :] - pts[:, None, :], axis=2), axis=1)
            if np.mean(nearest < REPEAT_SAMPLE_M) >= 0.5:
                laid += planes.areas[i]
                break
    return laid / total if total > 0 else 0.0


def rivals_repeat_share(reloc, trace: dict) -> float | None:
    """The largest :func:`repeat_share` over the rivals that made the traced decision ambiguous (scores as a rival
    within ``min_ambiguity_ratio`` of the best's), or None when the decision named no best pose."""
    from reloc.transforms import transform_from_rotation_translation

    hyps, decision, modes = trace.get("judged"), trace.get("decision"), trace.get("modes")
    if decision is None or decision.best < 0 or not modes:
        return None
    group, b = modes["group"], decision.best
    best_score = modes["score"][group[b]]
    T_best = transform_from_rotation_translation(hyps.R[b], hyps.t[b])
    shares, seen = [0.0], {group[b]}
    for i in range(len(hyps)):
        g = group[i]
        if g in seen:
            continue
        seen.add(g)
        if modes["rival"][g] > 0 and modes["rival"][g] * reloc.params.min_ambiguity_ratio >= best_score:
            T = transform_from_rotation_translation(hyps.R[i], hyps.t[i])
            shares.append(repeat_share(reloc.planes, T_best, T))
    return max(shares)


def _label(positive: bool, ambiguous: bool, res, T_true) -> str:
    from reloc.evaluation.metrics import classify
    from reloc.transforms import pose_error

    errors = pose_error(res.T_map_cam, T_true) if res.relocalized and positive else None
    return classify(positive, ambiguous and positive, res.relocalized, errors)


def grow_suite(directory: str, most: int, step: int) -> list[dict]:
    """One record per query of the saved suite in ``directory`` and per scene it is relocalized in: its label as
    the suite gives it and, when rejected as ambiguous, its rivals' ``repeat_share`` (:func:`rivals_repeat_share`)
    and each grown size's ``frames``, ``ambiguous`` label, ``label`` and ``ratio`` (None when no rival is left), and
    the matching time."""
    from reloc.evaluation.prepared_io import load_prepared
    from reloc.evaluation.suite import query_history
    from reloc.mapping import MappingParams, build_submap

    prep, _ = load_prepared(directory)
    spec, mapping = prep.spec, MappingParams()
    histories: dict = {}
    records = []
    for name in spec.scenes:
        reloc = prep.relocalizer(name)
        for q in prep.queries_in(name):
            positive = q.scene == name
            trace: dict = {}
            res = reloc.locate(q.submap, trace=trace)
            frames = q.window_frames or spec.window_frames
            rec = {"map": name, "query": q.name, "positive": positive, "label": _label(positive, q.ambiguous, res,
                                                                                      q.T_world_cam),
                   "reason": res.reason, "frames": frames, "grown": []}
            if not res.relocalized and res.reason.startswith("ambiguous"):
                rec["repeat_share"] = rivals_repeat_share(reloc, trace)
                if q.name not in histories:
                    histories[q.name] = query_history(spec, q.name)
                fetch, ambiguous = histories[q.name]
                k = frames
                while k < most:
                    k = min(most, k + step)
                    sets, poses = fetch(k)
                    if len(sets) <= (rec["grown"][-1]["frames"] if rec["grown"] else frames):
                        break  # the trajectory begins here
                    amb = ambiguous(len(sets)) if positive else False
                    t0 = time.perf_counter()
                    grown = reloc.locate(build_submap(sets, poses, mapping))
                    ms = (time.perf_counter() - t0) * 1e3
                    rec["grown"].append({
                        "frames": len(sets), "ambiguous": amb, "label": _label(positive, amb, grown, q.T_world_cam),
                        "ratio": grown.ambiguity_ratio if math.isfinite(grown.ambiguity_ratio) else None,
                        "reason": grown.reason, "ms": ms})
            records.append(rec)
    return records


def outcome(rec: dict, min_ratio: float, max_repeat_share: float | None = None) -> str:
    """The label of ``rec`` under the rule: the first grown answer with a ratio of at least ``min_ratio`` (None,
    no rival left, passes any), else a rejection labelled by the frames the window grew to. With
    ``max_repeat_share``, a query grows only when its rivals' repeat share is known and under it."""
    if not rec["grown"]:
        return rec["label"]
    if max_repeat_share is not None and not (rec.get("repeat_share") is not None
                                             and rec["repeat_share"] < max_repeat_share):
        return rec["label"]
    for g in rec["grown"]:
        if g["label"] in ("TP", "FP") and (g["ratio"] is None or g["ratio"] >= min_ratio):
            return g["label"]
    last = rec["grown"][-1]
    # Rejected at every size: a TN when its last frames are ambiguous (or it is a negative), else a FN.
    return "FN" if rec["positive"] and not last["ambiguous"] else "TN"


def summarize(records: list[dict], min_ratio: float | None, max_repeat_share: float | None = None) -> dict:
    """Counts of the labels under a rule (``min_ratio`` None: ours, no growth), and the queries whose label
    changed."""
    counts = {k: 0 for k in ("TP", "TN", "FP", "FN")}
    changed = []
    for rec in records:
        label = rec["label"] if min_ratio is None else outcome(rec, min_ratio, max_repeat_share)
        counts[label] += 1
        if label != rec["label"]:
            where = rec["query"] if rec["positive"] else f"{rec['query']} in {rec['map']}"
            changed.append(f"{where} {rec['label']}->{label}")
    tp, fn = counts["TP"], counts["FN"]
    return {**counts, "recall": tp / (tp + fn) if tp + fn else math.nan, "changed": changed}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prepared", action="append", required=True, metavar="DIR",
                    help="A saved suite (reloc_accuracy.py --save-prepared: a <source>_<noise> directory); "
                         "repeatable.")
    ap.add_argument("--most", type=int, default=120, help="Frames a window may grow to.")
    ap.add_argument("--step", type=int, default=20, help="Frames added at each size.")
    ap.add_argument("--min-ratio", default="1.55,3,inf",
                    help="Rules: the ambiguity ratio a grown answer needs (comma separated; inf: no rival left).")
    ap.add_argument("--max-repeat-share", default="0.3,0.5",
                    help="Rules that grow a query only when its rivals' repeat share is under this (comma "
                         "separated; any grown answer taken).")
    ap.add_argument("--name", default="window_growth", help="Result file stem in benchmarks/results/.")
    args = ap.parse_args(argv)
    name = results_name(args.name)
    try:
        rules = [float(x) for x in args.min_ratio.split(",")]
        shares = [float(x) for x in args.max_repeat_share.split(",")] if args.max_repeat_share else []
    except ValueError:
        ap.error(f"--min-ratio, --max-repeat-share: expected comma-separated numbers, got {args.min_ratio!r}, "
                 f"{args.max_repeat_share!r}")
    if args.step < 1 or args.most < 1 or any(not r >= 1.0 for r in rules):
        ap.error(f"--step, --most: expected >= 1, got {args.step}, {args.most}; --min-ratio: each >= 1, got {rules}")
    from reloc._numba import warm_up

    warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline"))
    rows, results = [], {}
    for directory in args.prepared:
        t0 = time.perf_counter()
        records = grow_suite(directory, args.most, args.step)
        took = time.perf_counter() - t0
        tag = Path(directory).absolute().parent.name + "/" + Path(directory).name
        base = summarize(records, None)
        per_rule = {"ours": base}
        for r in rules:
            per_rule[f"min ratio {r:g}"] = summarize(records, r)
        for share in shares:
            per_rule[f"repeats under {share:g}"] = summarize(records, 1.0, share)
        grown = [rec for rec in records if rec["grown"]]
        print(f"{tag}: {len(records)} queries, {len(grown)} grown, {took:.0f} s", flush=True)
        results[tag] = {"seconds": took, "grown_queries": len(grown), "rules": per_rule,
                        "grown_ms_mean": (sum(g["ms"] for rec in grown for g in rec["grown"])
                                          / max(1, sum(len(rec["grown"]) for rec in grown))),
                        "grown_records": grown}
        for rule, s in per_rule.items():
            rows.append([tag, rule, s["TP"], s["TN"], s["FP"], s["FN"], 100 * s["recall"], s["TP"] - base["TP"],
                         s["FP"] - base["FP"], "; ".join(c for c in s["changed"] if c.endswith("->FP"))])
    print_table(["suite", "rule", "TP", "TN", "FP", "FN", "R[%]", "dTP", "dFP", "false positives it adds"], rows,
                floatfmt=".1f")
    path = write_results(name, params=vars(args), results=results)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
