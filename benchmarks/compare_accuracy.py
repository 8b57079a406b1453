"""Two sets of ``reloc_accuracy.py`` records side by side: what a change did, suite by suite and view by view.

Each pair is a record before and one after (the same suite: the same queries and their labels), e.g. the recorded
tuned suite and replicates against fresh runs with a candidate default::

    .venv/bin/python benchmarks/compare_accuracy.py --name my_change \\
        benchmarks/results/reloc_accuracy.json:/tmp/new/reloc_accuracy.json \\
        benchmarks/results/reloc_accuracy_rooms_tour_replicate_a.json:/tmp/new/rt_a.json

With ``--variant KEY=VALUE``, each argument is one record holding ours and a variant evaluated beside it on the same
maps and queries (``reloc_accuracy.py --prepared DIR --variant KEY=VALUE``), and ours is compared with the variant::

    .venv/bin/python benchmarks/compare_accuracy.py --name my_change --variant hidden_rival_credit=True \
        /tmp/new/var_tuned.json /tmp/new/var_a.json

Per pair and source (``extraction/<sensor>/ours`` by default): TP / TN / FP / FN before and after, the outcomes that
changed (query, its scene's map, the labels, the reason after), and the maps' bent planes (``PlaneMap.consistency``);
then the totals per sensor over all pairs. Prints the tables and writes ``benchmarks/results/<name>.json`` (small:
the changed outcomes only, where a record holds every one).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import print_table, results_name, write_results  # noqa: E402

_COUNTS = ("TP", "TN", "FP", "FN")


def _load(path: str) -> dict:
    try:
        with open(path, encoding="utf-8") as f:
            record = json.load(f)
        record["results"]["sources"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SystemExit(f"{path}: expected a reloc_accuracy.py record (results.sources), got {e!r}")
    return record


# What makes two records' queries the same views (a query's name, office/robot/0, is the same under any seed):
# their seeds, scenes, kinds and counts, and the camera that saw them. Maps and windows may differ: that is what a
# comparison is for.
QUERY_FIELDS = ("query_seed", "scenes", "query_kinds", "queries_per_kind", "query_spacing_frames",
                "negatives_per_scene", "noise", "camera", "width", "height")


def same_queries(before: dict, after: dict, source: str) -> list[str]:
    """The fields of :data:`QUERY_FIELDS` in which the two records' specs of ``source`` (``extraction/kinect/ours``
    reads the spec ``extraction/kinect``) differ, as ``field: before -> after``; a record without a spec has none."""
    key = source.rsplit("/", 1)[0]
    a = ((before.get("params") or {}).get("spec") or {}).get(key) or {}
    b = ((after.get("params") or {}).get("spec") or {}).get(key) or {}
    return [f"{f}: {a.get(f)!r} -> {b.get(f)!r}" for f in QUERY_FIELDS if a.get(f) != b.get(f)]


def compare_source(before: dict, after: dict) -> dict:
    """One source of two records: counts, changed outcomes and map consistency, before and after."""
    def key(o):
        return o["scene"], o["query"]

    old = {key(o): o for o in before["outcomes"]}
    new = {key(o): o for o in after["outcomes"]}
    if old.keys() != new.keys():
        raise SystemExit(f"the records do not hold the same queries ({len(old.keys() ^ new.keys())} differ): "
                         "expected two runs of one suite")
    changed = [{"map": k[0], "query": k[1], "before": old[k]["label"], "after": new[k]["label"],
                "ambiguous": bool(new[k]["ambiguous"]), "reason_after": new[k]["reason"]}
               for k in old if old[k]["label"] != new[k]["label"]]

    def bent(src):
        c = src.get("map_consistency") or {}
        return {"planes": sum(v["bent_planes"] for v in c.values()),
                "area_m2": round(sum(v["bent_area_m2"] for v in c.values()), 2),
                "map_planes": sum((src.get("map_planes") or {}).values())}

    return {"before": {k: before["total"][k] for k in _COUNTS}, "after": {k: after["total"][k] for k in _COUNTS},
            "changed": changed, "bent_before": bent(before), "bent_after": bent(after),
            "prepare_s": [before.get("prepare_s"), after.get("prepare_s")]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pairs", nargs="+", metavar="BEFORE.json:AFTER.json",
                    help="Records of one suite, before and after (with --variant: one record each).")
    ap.add_argument("--variant", default=None, metavar="KEY=VALUE[,...]",
                    help="Compare each source with the variant beside it in the same record (the source "
                    "'<source> with KEY=VALUE' of reloc_accuracy.py --variant).")
    ap.add_argument("--sources", default="extraction/kinect/ours,extraction/tof/ours,extraction/stereo/ours",
                    help="Sources to compare (comma separated; those a record lacks are skipped).")
    ap.add_argument("--name", default="compare_accuracy", help="Result file stem in benchmarks/results/.")
    args = ap.parse_args(argv)
    try:
        name = results_name(args.name)
    except ValueError as e:
        ap.error(str(e))
    sources = [s for s in args.sources.split(",") if s]
    pairs, rows, totals = [], [], {}
    for pair in args.pairs:
        if args.variant is not None:
            a = b = pair
        elif pair.count(":") != 1:
            raise SystemExit(f"{pair!r}: expected BEFORE.json:AFTER.json")
        else:
            a, b = pair.split(":")
        ra = _load(a)
        rb = ra if b == a else _load(b)
        out = {"before": a, "after": b, "commits": [ra.get("git", {}).get("commit"), rb.get("git", {}).get("commit")],
               "sources": {}}
        for s in sources:
            s_after = s if args.variant is None else f"{s} with {args.variant}"
            if s not in ra["results"]["sources"] or s_after not in rb["results"]["sources"]:
                continue
            differ = same_queries(ra, rb, s)
            if differ:
                raise SystemExit(f"{a} and {b}: not the same queries for {s} ({'; '.join(differ)}): expected two "
                                 "runs of one suite")
            c = compare_source(ra["results"]["sources"][s], rb["results"]["sources"][s_after])
            out["sources"][s] = c
            moves = Counter((x["before"], x["after"]) for x in c["changed"])
            rows.append([Path(b).stem, s, " / ".join(str(c["before"][k]) for k in _COUNTS),
                         " / ".join(str(c["after"][k]) for k in _COUNTS),
                         ", ".join(f"{x}->{y} {n}" for (x, y), n in sorted(moves.items())),
                         f"{c['bent_before']['planes']} -> {c['bent_after']['planes']}"])
            t = totals.setdefault(s, {"before": Counter(), "after": Counter(), "bent_planes": [0, 0],
                                      "bent_area_m2": [0.0, 0.0]})
            t["before"].update(c["before"])
            t["after"].update(c["after"])
            t["bent_planes"][0] += c["bent_before"]["planes"]
            t["bent_planes"][1] += c["bent_after"]["planes"]
            t["bent_area_m2"][0] += c["bent_before"]["area_m2"]
            t["bent_area_m2"][1] += c["bent_after"]["area_m2"]
        if not out["sources"]:
            have = sorted(rb["results"]["sources"])
            raise SystemExit(f"{pair}: no source to compare (asked for {', '.join(sources)}"
                             f"{' with ' + args.variant if args.variant else ''}; the record holds {', '.join(have)})")
        pairs.append(out)
    print_table(["after", "source", "before TP/TN/FP/FN", "after", "changed", "bent planes"], rows)
    print()
    print_table(["source", "TP", "FP", "bent planes", "bent m^2"],
                [[s, f"{t['before']['TP']} -> {t['after']['TP']}", f"{t['before']['FP']} -> {t['after']['FP']}",
                  f"{t['bent_planes'][0]} -> {t['bent_planes'][1]}",
                  f"{t['bent_area_m2'][0]:.1f} -> {t['bent_area_m2'][1]:.1f}"] for s, t in totals.items()])
    for p in pairs:
        for s, c in p["sources"].items():
            for x in c["changed"]:
                if "FP" in (x["before"], x["after"]):
                    print(f"{Path(p['after']).stem} {s}: {x['query']} in the map of {x['map']}: {x['before']} -> "
                          f"{x['after']}")
    totals_out = {s: {"before": dict(t["before"]), "after": dict(t["after"]), "bent_planes": t["bent_planes"],
                      "bent_area_m2": [round(v, 2) for v in t["bent_area_m2"]]} for s, t in totals.items()}
    path = write_results(name, params={"pairs": args.pairs, "sources": sources, "variant": args.variant},
                         results={"pairs": pairs, "totals": totals_out})
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
