"""Relocalization accuracy on the simulated suite, like the paper's Table 1 (and Table 3 with --ablation).

Scenes: living room, office, apartment, corridor, the identical meeting rooms and the symmetric room. Per scene: a
map from a robot tour and a hand-held walk (3,000 frames each by default, keyframes by motion); positive queries
from other robot-like and hand-held trajectories (submaps of ``--window`` frames 3 apart, the ground-truth poses
standing for odometry, grown back in time up to ``--max-window`` frames while a submap cannot pin a pose:
``reloc.mapping.grow_submap``); 20 negative queries from the other scenes. Planes come from extraction on every frame
(320x240 Kinect-class camera for the kinect and ToF noise models, the 640x400 OAK-D class camera for stereo), once
per noise model, with extraction's noise law set to the simulated sensor's; the simulator's ground-truth planes run
as a second source (matching alone).

Side by side, on the same maps and queries:
- ``ours``: the default matcher;
- ``ours, no optimistic rivals``: a rival pose is judged only by what it explains (not also by its planes that
  land where the map knows nothing): more recall, at the price of guesses among identical rooms;
- ``paper settings``: the paper's decision rules only (fixed 1 m sphere distance, no extent filter, no free space,
  no explained fraction, no tight re-check, no ambiguity test: the best mode wins), as the baseline.

Counting (see reloc.evaluation.metrics): TP within 0.25 m and 5 deg; positives whose view repeats elsewhere in the
scene (identical rooms, symmetric room, periodic corridor) must be rejected: any pose for them is FP (a guess).
Goals: no false positive, recall >= 95%, median pose error < 3 cm and 0.5 deg.

    python benchmarks/reloc_accuracy.py [--noise kinect,tof,stereo] [--queries 10] [--window 40] [--max-window 120]
                                         [--ablation]

``--set KEY=VALUE`` (repeatable) changes an extraction parameter (ExtractionParams) for maps and queries alike, to
measure a candidate default; ``--mapping-set KEY=VALUE`` likewise a MappingParams field (the fusion of maps and of
the queries' submaps, ``NAME_deg`` for a ``NAME_rad`` field); with either, give ``--name`` so the recorded results
are not replaced. ``--variant KEY=VALUE[,KEY=VALUE...]`` (repeatable) adds a matcher with those MatchingParams
changed (``NAME_deg`` for a ``NAME_rad`` field in degrees), evaluated on the same maps and queries as ours, and
prints every query whose outcome it changes.

Preparing a source (rendering, extraction, map fusion, submaps) takes minutes; relocalizing its 240 queries takes
seconds. ``--save-prepared DIR`` keeps each source's maps and queries (``DIR/<source>_<noise>/``, .npz and JSON, no
pickle) and ``--prepared DIR`` loads them instead of preparing, for trying matcher settings (``--variant``) in
seconds: the suite's options and every extraction and fusion parameter (defaults, ``--set`` and ``--mapping-set``)
must be those it was saved with (an error says which differ), and a warning names the commit it was prepared at
when that is not this one (``--ablation`` still prepares its own).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import git_info, parse_overrides, print_table, quick_presets, results_name, write_results  # noqa: E402


def paper_settings(params):
    """The baseline: the paper's evaluation and decision rules only, on the same index and transforms (none of our
    additions: no free space, explained fraction, direction support, twin probe, decision over refined poses, lower
    projection share or wider refinement angle for noisy sensors, fallback refinement angle, refinement at the
    planes' centroids, conflict tests, facets left out of the explained fraction, stronger rivals among the planes
    not fed, far and sparse planes laid over larger ones left out, or far planes' conflicts forgiven)."""
    return replace(
        params, max_sphere_gap_m=1.0, gap_tolerance_m=1e3, extent_tolerance_m=1e3, min_explained_fraction=0.0,
        min_explained_known_fraction=0.0, facet_max_area_m2=0.0, well_matched_planes=0, noisy_well_matched_planes=0,
        min_competitor_fraction=0.0, free_space=False, min_direction_support_m2=0.0, hidden_against_support=False,
        conflicts_against_support=False, near_decision_offsets=False,
        max_conflict_area_m2=0.0, min_uncontradicted_planes=0, noisy_min_uncontradicted_planes=0,
        min_overlap=0.3, noisy_min_projection_ratio=1.0, noisy_refine_max_angle_rad=params.refine_max_angle_rad,
        refine_fallback_max_angle_rad=0.0,
        final_max_angle_rad=params.match_max_angle_rad, final_max_offset_m=params.match_max_offset_m,
        min_ambiguity_ratio=1.0, probe_twins=False, tight_decision=False, refine_at_centroids=False,
        stronger_rival_below_explained=0.0, far_overlay_sigma_m=0.0, sparse_overlay_sigma_m=0.0,
        far_conflict_min_planes=0,
    )


def parse_variant(spec: str, ours):
    """``ours`` with the MatchingParams changes of a ``--variant`` spec (``KEY=VALUE`` items separated by commas);
    ValueError naming what is wrong."""
    items = [s for s in re.split(r",(?=\s*\w+\s*=)", spec) if s.strip()]
    if not items:
        raise ValueError(f"--variant: expected KEY=VALUE[,KEY=VALUE...], got {spec!r}")
    return ours.with_(**parse_overrides(items, option="--variant"))


def changed_outcomes(base: list, other: list) -> list[str]:
    """One line per query whose label differs between two lists of outcomes of the same queries."""
    before = {(o.scene, o.query): o for o in base}
    lines = []
    for o in other:
        b = before[(o.scene, o.query)]
        if b.label != o.label:
            err = f" ({100 * o.translation_error_m:.1f} cm)" if math.isfinite(o.translation_error_m) else ""
            lines.append(f"{o.query} in the map of {o.scene}: {b.label} -> {o.label}{err}")
    return lines


def _row(label, s):
    return [label, s.TP, s.TN, s.FP, s.FN, s.ambiguous, 100 * s.precision if math.isfinite(s.precision) else None,
            100 * s.recall if math.isfinite(s.recall) else None, s.identifiable,
            100 * s.recall_identifiable if math.isfinite(s.recall_identifiable) else None, s.unique,
            100 * s.recall_unique if math.isfinite(s.recall_unique) else None,
            100 * s.median_translation_error_m if math.isfinite(s.median_translation_error_m) else None,
            s.median_rotation_error_deg if math.isfinite(s.median_rotation_error_deg) else None, s.mean_ms,
            s.median_ms]


HEAD = ["", "TP", "TN", "FP", "FN", "amb", "P[%]", "R[%]", "ident", "R_id[%]", "uniq", "R_un[%]", "t_err[cm]",
        "r_err[deg]", "mean[ms]", "med[ms]"]
FLOATFMT = ["", "", "", "", "", "", ".2f", ".2f", "", ".2f", "", ".2f", ".2f", ".3f", ".2f", ".2f"]


def main() -> int:
    from reloc.evaluation.suite import SUITE_MAP_TOUR, EvalSpec
    from sim.trajectories import TOURS

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--noise", default="kinect,tof,stereo", help="Noise models (comma separated).")
    ap.add_argument("--queries", type=int, default=10, help="Positive queries per trajectory kind and scene.")
    ap.add_argument("--negatives", type=int, default=20, help="Negative queries per scene.")
    ap.add_argument("--window", type=int, default=40, help="Frames per submap.")
    ap.add_argument("--max-window", type=int, default=None,
                    help="A submap that cannot pin a pose (too few planes, or too little area along its weakest "
                         "direction) grows back in time, half a window at a time, up to this many frames (default "
                         "3 x --window; 0 = windows do not grow, the suite before 2026-11-28).")
    ap.add_argument("--map-frames", type=int, default=3000, help="Frames per mapping trajectory.")
    ap.add_argument("--map-tour", choices=TOURS, default=SUITE_MAP_TOUR,
                    help="Where the mapping trajectories go: every room entered in turn, as a mapping run that "
                         "leaves no room out (the suite's since 2026-11-29), or shortest paths to random places "
                         "(the suite's before, and of the suites saved then).")
    ap.add_argument("--scenes", default=None, help="Scenes (comma separated; default: the six of the suite).")
    ap.add_argument("--no-oracle", action="store_true", help="Skip the ground-truth plane source.")
    ap.add_argument("--ablation", action="store_true", help="Also Table 3 (kinect noise, extraction).")
    ap.add_argument("--quick", action="store_true", help="A smoke run (two scenes, kinect, few queries).")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="ExtractionParams override for maps and queries (repeatable; VALUE parsed as a Python "
                         "literal or taken as a string), to measure a candidate default")
    ap.add_argument("--mapping-set", action="append", default=[], metavar="KEY=VALUE",
                    help="MappingParams override for maps and submaps alike (repeatable; NAME_deg for a NAME_rad "
                         "field), to measure a candidate default of the map fusion")
    ap.add_argument("--variant", action="append", default=[], metavar="KEY=VALUE[,KEY=VALUE...]",
                    help="A matcher with these MatchingParams changed (NAME_deg for a NAME_rad field), evaluated "
                         "beside ours on the same maps and queries (repeatable)")
    ap.add_argument("--query-seed", type=int, default=EvalSpec.query_seed,
                    help="Seed of the query trajectories and their noise (positives, and through them the negatives): "
                         "another value is a replicate of the suite on queries no default was tuned on.")
    ap.add_argument("--map-seed", type=int, default=EvalSpec.map_seed,
                    help="Seed of the mapping trajectories and their noise.")
    ap.add_argument("--name", default="reloc_accuracy", help="Result file stem in benchmarks/results/.")
    ap.add_argument("--save-prepared", metavar="DIR", type=Path, default=None,
                    help="Also save each source's maps and queries under DIR/<source>_<noise>/ (8-15 MB each).")
    ap.add_argument("--prepared", metavar="DIR", type=Path, default=None,
                    help="Load the maps and queries saved by --save-prepared instead of preparing them (seconds "
                         "instead of minutes): for comparing matchers (--variant). The suite and every extraction "
                         "and fusion parameter (defaults, --set, --mapping-set) must be those it was saved with.")
    args = ap.parse_args()
    if args.max_window is not None and 0 < args.max_window < args.window or (args.max_window or 0) < 0:
        ap.error(f"--max-window: expected 0 or at least --window ({args.window}), got {args.max_window}")

    from sim import KERNEL_MODULES as SIM_KERNELS

    from reloc._numba import warm_up
    from reloc.evaluation.metrics import summarize
    from reloc.evaluation.prepared_io import PreparedSuiteError, built_with, load_prepared, mismatch, save_prepared
    from reloc.evaluation.suite import SCENES, prepare_suite, run_ablation, suite_spec
    from reloc.extraction import ExtractionParams
    from reloc.mapping import MappingParams
    from reloc.mapping.plane_map import BENT_FRACTION, BENT_OFF_M
    from reloc.matching import ABLATIONS, MatchingParams

    try:
        results_name(args.name)
        set_overrides = parse_overrides(args.set)
        mapping_overrides = parse_overrides(args.mapping_set, "--mapping-set")
        extraction = ExtractionParams().with_(**set_overrides) if set_overrides else None
        mapping = MappingParams().with_(**mapping_overrides)
        variants = {f"ours with {spec}": parse_variant(spec, MatchingParams()) for spec in args.variant}
    except ValueError as exc:
        ap.error(str(exc))

    if args.quick:  # what the command line gives wins
        quick_presets(ap, args, {"noise": "kinect", "queries": 3, "negatives": 6, "map_frames": 800,
                                 "scenes": "living_room,office"})
    scenes = tuple(args.scenes.split(",")) if args.scenes else SCENES
    sources = [("extraction", n) for n in args.noise.split(",")]
    if not args.no_oracle:
        sources.append(("oracle", args.noise.split(",")[0]))
    if args.prepared is not None:
        for source, noise in sources:
            if not (args.prepared / f"{source}_{noise}" / "suite.json").is_file():
                ap.error(f"--prepared: {args.prepared / f'{source}_{noise}'} holds no prepared suite (save one with "
                         "--save-prepared and the same options)")
    warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline", *SIM_KERNELS))
    ours = MatchingParams()
    methods = {"ours": ours, "ours, no optimistic rivals": replace(ours, optimistic_rivals=False),
               "paper settings": paper_settings(ours), **variants}

    def suite(noise, **kw):
        """The suite of reloc eval (reloc.evaluation.suite.suite_spec), so that its tables reproduce these."""
        return suite_spec(noise, scenes=scenes, queries=args.queries, negatives=args.negatives, window=args.window,
                          max_window=args.max_window, map_frames=args.map_frames, query_seed=args.query_seed,
                          map_seed=args.map_seed, map_tour=args.map_tour, **kw)

    # The overrides, as JSON reads them back, go with a saved suite for the record (every parameter is compared).
    overrides = json.loads(json.dumps({"set": set_overrides, "mapping_set": mapping_overrides}))
    here = git_info()
    summary_rows, results = [], {}
    for source, noise in sources:
        spec = suite(noise, plane_source=source)
        t0 = time.perf_counter()
        origin = None  # where a loaded suite came from (the results name it)
        if args.prepared is not None:
            where = args.prepared / f"{source}_{noise}"
            try:
                prepared, meta = load_prepared(where)
            except PreparedSuiteError as exc:
                ap.error(f"--prepared: {exc}")
            problems = mismatch(prepared, meta, spec, built_with(spec, extraction, mapping))
            if problems:
                ap.error(f"--prepared: {where} holds another suite than this command asks for: {'; '.join(problems)}")
            if meta.get("commit") != here["commit"] or meta.get("dirty") or here["dirty"]:
                print(f"warning: {where} was prepared at commit {meta.get('commit')}"
                      f"{' with uncommitted changes' if meta.get('dirty') else ''}, this is {here['commit']}"
                      f"{' with uncommitted changes' if here['dirty'] else ''}: its maps and queries come from "
                      "the extraction and fusion of then")
            origin = {"dir": str(where), "commit": meta.get("commit"), "dirty": meta.get("dirty")}
        else:
            prepared = prepare_suite(spec, mapping, extraction=extraction)
        prep_s = time.perf_counter() - t0
        if args.save_prepared is not None:
            saved = save_prepared(args.save_prepared / f"{source}_{noise}", prepared,
                                  {"params": built_with(spec, extraction, mapping), "overrides": overrides,
                                   "commit": here["commit"], "dirty": here["dirty"]})
            print(f"{source}/{noise}: saved the prepared suite to {saved.parent}")
        # The windows' odometry is the ground truth here, so every frame the odometry check leaves out is a loss.
        left_out = {name: sum(q.frames_left_out for q in qs) for name, qs in prepared.queries.items()}
        sizes = [q.window_frames or spec.window_frames for qs in prepared.queries.values() for q in qs]
        grown = sum(s > spec.window_frames for s in sizes)
        print(f"{source}/{noise}: odometry check left out {sum(left_out.values())} of "
              f"{sum(sizes)} window frames (exact odometry) {left_out}; {grown} of {len(sizes)} windows grew")
        # How well the maps' planes fit their own samples (a plane fused from two surfaces shows here).
        consistency = {name: m.consistency() for name, m in prepared.maps.items()}
        print(f"{source}/{noise}: map planes with over {BENT_FRACTION:.0%} of their samples more than "
              f"{100 * BENT_OFF_M:.0f} cm off (count, m^2): "
              + ", ".join(f"{k} {v['bent_planes']} ({v['bent_area_m2']:.1f})" for k, v in consistency.items()))
        ours_outcomes = None
        for label, params in methods.items():
            rows = prepared.evaluate(params)
            outcomes = [o for r in rows for o in r.outcomes]
            if label == "ours":
                ours_outcomes = outcomes
            elif label in variants:
                lines = changed_outcomes(ours_outcomes, outcomes)
                print(f"{source}/{noise}: {label}: {len(lines)} outcome(s) differ from ours"
                      + "".join(f"\n  {line}" for line in lines))
            per_scene = [r.summary() for r in rows]
            total = summarize("all", outcomes)
            key = f"{source}/{noise}/{label}"
            if label == "ours":
                print_table(HEAD, [_row(s.name, s) for s in per_scene + [total]],
                            title=f"Table 1 analogue: {source} planes, {noise} noise, {label}",
                            floatfmt=FLOATFMT)
            summary_rows.append(_row(f"{source}/{noise}: {label}", total))
            results[key] = {
                "prepare_s": prep_s,
                "prepared_from": origin,
                "frames_left_out": left_out,
                "map_planes": {r.scene: r.map_planes for r in rows},
                "map_consistency": consistency,
                "per_scene": [s.to_dict() for s in per_scene],
                "total": total.to_dict(),
                "outcomes": [o.to_dict() for o in outcomes],
            }
    print_table(HEAD, summary_rows, title="All scenes: ours and the paper's decision rules side by side",
                floatfmt=FLOATFMT)
    ablation = None
    if args.ablation:
        spec = suite("kinect", plane_source="extraction")
        out = run_ablation(spec, ABLATIONS, ours, mapping, extraction=extraction)
        rows = [_row(v, summarize(v, [o for r in res for o in r.outcomes])) for v, res in out.items()]
        print_table(HEAD, rows, title="Table 3 analogue: ablations (extraction planes, kinect noise)",
                    floatfmt=FLOATFMT)
        ablation = {v: summarize(v, [o for r in res for o in r.outcomes]).to_dict() for v, res in out.items()}
    main_key = f"extraction/{args.noise.split(',')[0]}/ours"
    t = results[main_key]["total"]
    verdict = {
        "fp": t["FP"], "no_false_positive": t["FP"] == 0,
        "recall": t["recall"], "recall_goal": 0.95, "recall_ok": bool(t["recall"] and t["recall"] >= 0.95),
        "median_t_err_m": t["median_translation_error_m"], "median_r_err_deg": t["median_rotation_error_deg"],
        "error_ok": bool(t["median_translation_error_m"] is not None and t["median_translation_error_m"] < 0.03
                         and t["median_rotation_error_deg"] < 0.5),
        "false_positives_all_sources": {k: v["total"]["FP"] for k, v in results.items()},
        # Positives whose true pose the map confirms (the rest no search can answer under the acceptance rules)
        # and the recall over them: what the search and the decision lose.
        "identifiable": t["identifiable"], "recall_identifiable": t["recall_identifiable"],
        "recall_ceiling": round(t["identifiable"] / (t["TP"] + t["FN"]), 6) if t["TP"] + t["FN"] else None,
        # Of those, the ones no symmetric twin of the true pose is confirmed for as well (the rest the planes
        # cannot tell from a twin under the acceptance rules), and the recall over them.
        "unique": t.get("unique"), "recall_unique": t.get("recall_unique"),
    }
    print(f"goals ({main_key}): FP {verdict['fp']} (none: {verdict['no_false_positive']}), recall "
          f"{verdict['recall']} (>= 0.95: {verdict['recall_ok']}), median errors {verdict['median_t_err_m']} m "
          f"{verdict['median_r_err_deg']} deg (< 3 cm and 0.5 deg: {verdict['error_ok']}); identifiable "
          f"{verdict['identifiable']} of {t['TP'] + t['FN']} positives (the recall's ceiling under the acceptance "
          f"rules {verdict['recall_ceiling']}), recall over them {verdict['recall_identifiable']}; unique (no twin "
          f"of the true pose confirmed too) {verdict['unique']}, recall over them {verdict['recall_unique']}")
    specs = {f"{source}/{noise}": asdict(suite(noise, plane_source=source)) for source, noise in sources}
    path = write_results(args.name, params={**vars(args), "spec": specs},
                         results={"sources": results, "ablation": ablation, "verdict": verdict})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
