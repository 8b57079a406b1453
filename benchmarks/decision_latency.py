"""Matcher times of ours and variants side by side on a prepared suite: what a change to matching costs.

``reloc_accuracy.py --prepared DIR --variant KEY=VALUE`` evaluates a variant beside ours, but one pass after the
other: on a shared 2-core machine the load moves between the passes and their mean times differ by more than most
changes cost. Here every query of the suite (positives and negatives, in their maps, as ``reloc eval`` relocalizes
them) is relocalized by each matcher in turn, ``--repeats`` times, and each matcher keeps its fastest time per
query; the table gives the mean, median and 95th percentile of the total and of the stages the variant may touch::

    .venv/bin/python benchmarks/decision_latency.py --prepared DIR/extraction_kinect \\
        --variant hidden_rival_credit=True --repeats 3 --name NAME

``--modes-anew`` adds our matcher with every mode of the decisions over refined poses worked out anew in each round
of the incremental input (``Relocalizer(reuse_modes=False)``, as before they were kept per query): the same results,
timed beside ours.

The kernels are warmed up (one pass of every matcher over the first scene's queries) before anything is timed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import print_table, results_name, write_results  # noqa: E402
from reloc_accuracy import parse_variant  # noqa: E402

ANEW = "ours, modes worked out anew each round"
STAGES = ("total", "prepare", "select", "verify", "decide", "decide.tighten", "refine")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--prepared", type=Path, required=True,
                    help="A prepared suite (a DIR/<source>_<noise> of reloc_accuracy.py --save-prepared).")
    ap.add_argument("--variant", action="append", default=[], metavar="KEY=VALUE[,KEY=VALUE...]",
                    help="A matcher with these MatchingParams changed, timed beside ours (repeatable).")
    ap.add_argument("--modes-anew", action="store_true",
                    help="Also time ours with the refined modes worked out anew in every round (reuse_modes=False).")
    ap.add_argument("--repeats", type=int, default=3, help="Passes per matcher and query (the fastest counts).")
    ap.add_argument("--name", default="decision_latency", help="Result file stem in benchmarks/results/.")
    args = ap.parse_args(argv)
    try:
        name = results_name(args.name)
        methods = {"ours": None}
        for spec in args.variant:
            methods[f"ours with {spec}"] = spec
        if args.modes_anew:
            methods[ANEW] = None
    except ValueError as e:
        ap.error(str(e))
    if args.repeats < 1:
        ap.error(f"--repeats: expected at least 1, got {args.repeats}")

    from reloc._numba import warm_up
    from reloc.evaluation.prepared_io import PreparedSuiteError, load_prepared
    from reloc.matching import MatchingParams

    try:
        prepared, _ = load_prepared(args.prepared)
    except PreparedSuiteError as exc:
        ap.error(f"--prepared: {exc}")
    try:
        params = {label: MatchingParams() if spec is None else parse_variant(spec, MatchingParams())
                  for label, spec in methods.items()}
    except ValueError as e:
        ap.error(str(e))
    spec = prepared.spec
    work = []  # (scene, relocalizer per method, queries)
    for scene in spec.scenes:
        qs = prepared.queries_in(scene)
        relocs = {label: prepared.relocalizer(scene, p) for label, p in params.items()}
        if ANEW in relocs:
            relocs[ANEW].reuse_modes = False
        work.append((scene, relocs, qs))
    # Warm-up: the kernels, then every matcher over the first scene's queries (caches).
    warm_up(("reloc.matching._kernels",))
    _, relocs, qs = work[0]
    for q in qs:
        for r in relocs.values():
            r.locate(q.submap)
    best = {label: [] for label in methods}  # per method: per query, the fastest pass's stage times
    differ = 0  # queries whose results ours and ANEW do not share
    for scene, relocs, qs in work:
        for q in qs:
            fastest = {label: None for label in methods}
            for rep in range(args.repeats):
                got = {}
                for label, r in relocs.items():
                    res = got[label] = r.locate(q.submap)
                    t = res.timings_ms
                    if fastest[label] is None or t.get("total", np.inf) < fastest[label].get("total", np.inf):
                        fastest[label] = dict(t)
                if ANEW in got and rep == 0:
                    a, b = got["ours"], got[ANEW]
                    same_pose = (a.T_map_cam is None) == (b.T_map_cam is None) and (
                        a.T_map_cam is None or np.array_equal(a.T_map_cam, b.T_map_cam))
                    differ += int(a.status != b.status or a.reason != b.reason or not same_pose)
            for label in methods:
                best[label].append(fastest[label])
    rows, out = [], {}
    for label in methods:
        stats = {}
        for stage in STAGES:
            v = np.array([t.get(stage, 0.0) for t in best[label]])
            stats[stage] = {"mean": float(v.mean()), "median": float(np.median(v)), "p95": float(np.percentile(v, 95))}
        out[label] = {"queries": len(best[label]), "ms": stats}
        rows.append([label] + [f"{stats[s]['mean']:.2f} / {stats[s]['median']:.2f} / {stats[s]['p95']:.2f}"
                               for s in STAGES])
    print_table(["matcher (ms: mean / median / p95)", *STAGES], rows,
                title=f"{args.prepared}: {len(best['ours'])} queries, fastest of {args.repeats} passes each")
    if args.modes_anew:
        out[ANEW]["results_differ"] = differ
        print(f"{ANEW}: results differ from ours in {differ} of {len(best['ours'])} queries (status, reason, pose)")
    path = write_results(name, params={"prepared": str(args.prepared), "variants": args.variant,
                                       "modes_anew": args.modes_anew, "repeats": args.repeats, "noise": spec.noise},
                         results=out)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
