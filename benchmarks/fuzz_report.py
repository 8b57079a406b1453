"""Fuzzing report: every input boundary fed many generated cases, outside pytest, with the outcomes counted.

The targets are the ones of the fuzz tests (``tests/test_fuzz_*.py``, each module's ``TARGET``: a hypothesis strategy
and ``run(case)``), run here with more cases. Each case ends as

- ``ok``: a result, checked to be right by the target (e.g. a config that loads is usable by every stage);
- ``error``: the target's own clear error (ValueError or its subclass, naming the input);
- ``escape``: anything else (another exception type, a wrong result, a hang past the time limit).

The serial decoder's fuzzer (``tests/test_protocol_fuzz.py``) is run too: random streams of frames, each possibly
corrupted, chunked at random; an escape there is an exception, a corrupted frame accepted or an intact one lost.

Usage (from the repository root)::

    nice -n 10 .venv/bin/python benchmarks/fuzz_report.py [--cases 1000] [--seed 0] [--only config,png]

Prints a table and writes ``benchmarks/results/fuzz_report.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
import warnings
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))

from _common import print_table, write_results  # noqa: E402

MODULES = {
    "config": "test_fuzz_config",
    "map_file": "test_fuzz_mapfile",
    "sequence": "test_fuzz_sequence",
    "point_cloud": "test_fuzz_pointcloud",
    "png": "test_fuzz_png",
    "depth_frame": "test_fuzz_depth",
    "geometry": "test_fuzz_geometry",
    "relocalizer": "test_fuzz_geometry:RELOC_TARGET",
}


def load_target(spec: str):
    import importlib

    module, _, attr = spec.partition(":")
    return getattr(importlib.import_module(module), attr or "TARGET")


def fuzz_target(target, cases: int, seed: int, max_escapes_kept: int = 5) -> dict:
    """Feed ``cases`` generated cases to ``target``; count outcomes, keep the first escapes."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import seed as hyp_seed

    from test_fuzz_common import Hang

    counts: Counter = Counter()
    escapes: list[dict] = []

    @hyp_seed(seed)
    @settings(max_examples=cases, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(target.cases)
    def drive(case):
        try:
            counts[target.run(case)] += 1
        except (Exception, Hang) as exc:  # noqa: BLE001 - every escape is counted, whatever it is
            counts["escape"] += 1
            if len(escapes) < max_escapes_kept:
                escapes.append({
                    "type": type(exc).__name__, "message": str(exc)[:500],
                    "case": repr(case)[:300], "where": traceback.format_exc(limit=-3)[-1500:],
                })

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        drive()
    seconds = time.perf_counter() - t0
    tried = sum(counts.values())
    return {"input": target.input, "tried": tried, "ok": counts["ok"], "error": counts["error"],
            "escape": counts["escape"], "seconds": round(seconds, 2), "escapes": escapes}


def fuzz_serial(streams: int, seed: int) -> dict:
    """The serial decoder's stream fuzzer: ``streams`` streams of 40 frames each."""
    from test_protocol_fuzz import run_fuzz

    counts: Counter = Counter()
    escapes = []
    frames_bad = frames_good = 0
    t0 = time.perf_counter()
    for s in range(seed, seed + streams):
        try:
            sent, intact, out, stats = run_fuzz(s)
            bad = [p.seq for p in out if p.seq not in sent or sent[p.seq] != (p.stamp_ns, p.message)]
            lost = set(intact) - {p.seq for p in out}
            if bad or lost:
                raise AssertionError(f"stream {s}: corrupted frames accepted {bad}, intact frames lost {sorted(lost)}")
            counts["ok"] += 1
            frames_bad += stats.frames_bad
            frames_good += stats.frames_good
        except Exception as exc:  # noqa: BLE001
            counts["escape"] += 1
            if len(escapes) < 5:
                escapes.append({"type": type(exc).__name__, "message": str(exc)[:500], "case": f"seed {s}"})
    return {"input": "serial bytes (40 frames per stream)", "tried": streams, "ok": counts["ok"], "error": 0,
            "escape": counts["escape"], "seconds": round(time.perf_counter() - t0, 2), "escapes": escapes,
            "frames_good": frames_good, "frames_bad": frames_bad}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=1000, help="generated cases per target (default 1000)")
    ap.add_argument("--seed", type=int, default=0, help="hypothesis seed (the same seed gives the same cases)")
    ap.add_argument("--only", default="", help="comma-separated targets (default: all), e.g. config,png,serial")
    ap.add_argument("--no-write", action="store_true", help="print only, do not write the JSON")
    args = ap.parse_args(argv)
    if args.cases < 1:
        ap.error(f"--cases: expected >= 1, got {args.cases}")
    names = [*MODULES, "serial"]
    only = [n for n in args.only.split(",") if n]
    unknown = set(only) - set(names)
    if unknown:
        ap.error(f"--only: unknown targets {sorted(unknown)}; expected some of {names}")
    results = {}
    for name in only or names:
        if name == "serial":
            results[name] = fuzz_serial(args.cases, args.seed)
        else:
            results[name] = fuzz_target(load_target(MODULES[name]), args.cases, args.seed)
        r = results[name]
        print(f"{name}: {r['tried']} cases, {r['ok']} ok, {r['error']} clear errors, {r['escape']} escapes "
              f"({r['seconds']} s)", flush=True)
        for e in r["escapes"]:
            print(f"  ESCAPE {e['type']}: {e['message'][:200]}\n    case: {e['case'][:200]}", flush=True)
    rows = [(n, r["input"], r["tried"], r["ok"], r["error"], r["escape"], r["seconds"]) for n, r in results.items()]
    total = [sum(r[k] for r in results.values()) for k in ("tried", "ok", "error", "escape")]
    rows.append(("total", "", *total, round(sum(r["seconds"] for r in results.values()), 1)))
    print()
    print_table(["target", "input", "cases", "ok", "clear error", "escape", "seconds"], rows,
                title=f"Fuzzing every input boundary ({args.cases} cases per target, seed {args.seed})",
                floatfmt=".1f")
    if not args.no_write:
        path = write_results("fuzz_report", params={"cases_per_target": args.cases, "seed": args.seed,
                                                    "targets": only or names}, results=results)
        print(f"wrote {path}")
    return 1 if total[3] else 0


if __name__ == "__main__":
    sys.exit(main())
