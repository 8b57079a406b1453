"""The main job: simulate a scene, build its map, relocalize positive and negative queries, print the results.

:func:`run_demo` is the whole demo as a function returning its figures (the ``reloc demo`` command prints them and
writes them as JSON). It uses the evaluation suite's steps (:mod:`reloc.evaluation.suite`) on one scene: the map
from a robot tour and a hand-held walk, positive queries from other trajectories of the same scene, negative
queries from another scene, with plane extraction on every frame (or the simulator's ground-truth planes). With two
usable cores, a helper process makes the negative queries while the demo's process builds the map and the positive
queries (``RELOC_DEMO_HELPER=0``: all in one process; the outcomes are the same).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["DemoSpec", "run_demo", "format_demo"]


@dataclass(frozen=True)
class DemoSpec:
    scene: str = "living_room"
    negative_scene: str = "office"
    plane_source: str = "extraction"
    noise: str = "kinect"
    camera: str = "kinect"
    width: int = 320
    height: int = 240
    map_trajectories: tuple[tuple[str, int], ...] = (("robot", 1500), ("handheld", 1500))
    queries_per_kind: int = 5
    negatives: int = 10
    window_frames: int = 40
    window_stride: int = 3
    window_max_frames: int = 120  # a submap that cannot pin a pose grows back in time up to this many frames
    seed: int = 1


def _percentiles(values) -> dict:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if not len(v):
        return {"median": None, "p95": None, "mean": None}
    return {"median": round(float(np.median(v)), 3), "p95": round(float(np.percentile(v, 95)), 3),
            "mean": round(float(v.mean()), 3)}


def _say_above_progress(line: str) -> None:
    """One line on stderr that a progress bar (``reloc demo``'s) does not overwrite."""
    import sys

    from tqdm import tqdm

    tqdm.write(line, file=sys.stderr)


def _plan(spec: DemoSpec, cfg):
    """The suite spec of the demo's queries and map, and its extraction (None for ground-truth planes) and mapping
    parameters from ``cfg``."""
    from reloc.evaluation.suite import EvalSpec, extraction_for_sensor
    from reloc.mapping import MappingParams

    base = EvalSpec(scenes=(spec.scene,), noise=spec.noise, camera=spec.camera, width=spec.width, height=spec.height,
                    map_trajectories=spec.map_trajectories, map_seed=spec.seed, queries_per_kind=spec.queries_per_kind,
                    query_seed=100 + spec.seed, window_frames=spec.window_frames, window_stride=spec.window_stride,
                    window_max_frames=spec.window_max_frames,
                    query_spacing_frames=max(60, spec.window_stride * spec.window_frames + 1),
                    plane_source=spec.plane_source)
    extraction = None
    if spec.plane_source == "extraction":
        from reloc.extraction import ExtractionParams

        extraction = extraction_for_sensor(base, ExtractionParams.from_config(cfg))
    return base, extraction, MappingParams.from_config(cfg)


def _negative_queries(spec: DemoSpec, base, extraction, mapping) -> list:
    """The demo's negative queries: ``spec.negatives`` windows of the other scene (its robot and hand-held
    trajectories, seeds of their own)."""
    from sim.scenes import make_scene

    from reloc.evaluation.suite import make_plane_source, make_queries

    other = make_scene(spec.negative_scene)
    neg_spec = replace(base, queries_per_kind=max(1, math.ceil(spec.negatives / len(base.query_kinds))),
                       query_seed=200 + spec.seed)
    return make_queries(other, neg_spec, make_plane_source(spec.plane_source, other, extraction=extraction),
                        mapping)[: spec.negatives]


def _start_negatives_helper(spec: DemoSpec, cfg) -> tuple[subprocess.Popen | None, Path | None]:
    """A process making the negative queries into ``negatives.npz`` of a new temporary directory
    (:func:`_helper_main`), and that directory (the caller removes it); ``(None, None)`` with fewer than two usable
    cores, no negatives or ``RELOC_DEMO_HELPER=0`` in the environment, and when it cannot start (no temporary
    directory, no process)."""
    from reloc import _numba

    if spec.negatives <= 0 or os.environ.get("RELOC_DEMO_HELPER", "1") == "0" or _numba._usable_cores() < 2:
        return None, None
    code = "import sys\nfrom reloc.demo import _helper_main\nsys.exit(_helper_main(sys.argv[1]))\n"
    tmp = None
    try:
        tmp = Path(tempfile.mkdtemp(prefix="reloc-demo-"))
        job = tmp / "job.json"
        job.write_text(json.dumps({"spec": asdict(spec), "config": cfg.model_dump(mode="json"),
                                   "out": str(tmp / "negatives.npz")}), encoding="utf-8")
        return subprocess.Popen([sys.executable, "-c", code, str(job)], env=_numba.helper_env(),
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL), tmp
    except OSError:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        return None, None


def _negatives_from_helper(helper: subprocess.Popen | None, directory: Path | None) -> list | None:
    """The helper's negative queries once it has finished, or None when there is no helper or it failed (then the
    caller makes them itself)."""
    from reloc.evaluation.prepared_io import PreparedSuiteError, load_queries

    if helper is None or directory is None or helper.wait() != 0:
        return None
    try:
        return load_queries(directory / "negatives.npz")
    except PreparedSuiteError:
        return None


def _helper_main(job_path: str) -> int:
    """The helper process of :func:`_start_negatives_helper`: reads its job (the demo spec and config as JSON),
    makes the negative queries and writes them (:func:`reloc.evaluation.prepared_io.save_queries`)."""
    from reloc.config import Config
    from reloc.evaluation.prepared_io import save_queries

    job = json.loads(Path(job_path).read_text(encoding="utf-8"))
    spec = DemoSpec(**{k: (tuple(tuple(x) for x in v) if k == "map_trajectories" else v)
                       for k, v in job["spec"].items()})
    base, extraction, mapping = _plan(spec, Config.model_validate(job["config"]))
    save_queries(job["out"], _negative_queries(spec, base, extraction, mapping))
    return 0


def run_demo(spec: DemoSpec | None = None, cfg=None, *, progress: Callable[[str, int, int], None] | None = None,
             keep: dict | None = None) -> dict:
    """Run the demo; ``progress(step, done, total)`` is called as it goes. Returns the figures as a JSON-able dict:
    counts (TP, TN, FP, FN), precision, recall, pose errors, per-stage latency, and the time of each phase.

    ``keep``: a dict that receives what the pictures need (``scene``, ``plane_source``, ``plane_map``,
    ``relocalizer``, ``queries``, in the order of the outcomes)."""
    from sim.scenes import make_scene

    from reloc._numba import warm_up
    from reloc.config import Config
    from reloc.evaluation.metrics import summarize
    from reloc.evaluation.suite import (
        build_scene_map,
        evaluate_queries,
        extraction_for_sensor,
        make_plane_source,
        make_queries,
    )
    from reloc.matching import MatchingParams, Relocalizer, scaled_to_sensor

    spec = spec or DemoSpec()
    from sim.scenes import SCENE_NAMES

    for what, name in (("scene", spec.scene), ("negative_scene", spec.negative_scene)):
        if name not in SCENE_NAMES:  # before compiling, which takes a minute on a cold cache
            raise ValueError(f"{what}: expected one of {', '.join(SCENE_NAMES)}, got {name!r}")
    if spec.negative_scene == spec.scene:  # its views would be counted as positives
        raise ValueError(f"negative_scene: expected a scene other than the mapped one ({spec.scene!r})")
    cfg = cfg or Config()
    step = progress or (lambda *_: None)
    phases = {}
    t0 = time.perf_counter()
    step("compile", 0, 1)
    from sim import KERNEL_MODULES as SIM_KERNELS

    info = warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline", *SIM_KERNELS),
                   say=_say_above_progress)
    phases["compile_s"] = time.perf_counter() - t0
    step("compile", 1, 1)

    base, extraction, mapping = _plan(spec, cfg)
    scene = make_scene(spec.scene)
    # The decision's offsets follow the simulated sensor's noise law, as for a live camera (and as reloc eval does).
    sensor = extraction_for_sensor(base)
    matching = scaled_to_sensor(MatchingParams.from_config(cfg), sensor.noise_model, sensor.noise_coeff)
    source = make_plane_source(spec.plane_source, scene, extraction=extraction)

    # The negative queries are made by a helper process on the second core while this one builds the map and the
    # positive queries (the same code and seeds: the same queries); without one, here after the positives.
    helper, tmp = _start_negatives_helper(spec, cfg)
    try:
        t = time.perf_counter()
        step("map", 0, 1)
        plane_map = build_scene_map(scene, base, source, mapping)
        phases["map_s"] = time.perf_counter() - t
        step("map", 1, 1)

        t = time.perf_counter()
        step("queries", 0, 2)
        positives = make_queries(scene, base, source, mapping)
        step("queries", 1, 2)
        negatives = _negatives_from_helper(helper, tmp)
        by_helper = negatives is not None
        if negatives is None:
            negatives = _negative_queries(spec, base, extraction, mapping)
        phases["queries_s"] = time.perf_counter() - t
        step("queries", 2, 2)
    finally:
        if helper is not None and helper.poll() is None:
            helper.kill()
            helper.wait()
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)

    t = time.perf_counter()
    reloc = Relocalizer(plane_map, matching)
    queries = positives + negatives
    done = [0]

    def tick(n):
        done[0] += n
        step("relocalize", done[0], len(queries))

    outcomes = evaluate_queries(reloc, queries, spec.scene, tick)
    phases["relocalize_s"] = time.perf_counter() - t
    if keep is not None:
        keep.update(scene=scene, plane_source=source, plane_map=plane_map, relocalizer=reloc, queries=queries)
    phases["total_s"] = time.perf_counter() - t0

    s = summarize(spec.scene, outcomes)
    stages = sorted({k for o in outcomes for k in o.timings_ms})
    latency = {k: _percentiles([o.timings_ms.get(k) for o in outcomes]) for k in stages}
    latency["relocalization_total"] = _percentiles([o.total_ms for o in outcomes])
    return {
        "spec": asdict(spec),
        "map": {"planes": len(plane_map), "keyframes": plane_map.meta.get("keyframe_count"),
                "free_space_m3": plane_map.summary()["free_space_m3"], "index_ms": round(reloc.index.build_ms, 3)},
        "queries": {"positive": len(positives), "negative": len(negatives),
                    "ambiguous": sum(o.ambiguous for o in outcomes), "negatives_by_helper": by_helper},
        "counts": {"TP": s.TP, "TN": s.TN, "FP": s.FP, "FN": s.FN},
        "precision": None if not math.isfinite(s.precision) else round(s.precision, 4),
        "recall": None if not math.isfinite(s.recall) else round(s.recall, 4),
        # Positives whose true pose the map confirms (reloc.evaluation.metrics) and the recall over them.
        "identifiable": s.identifiable,
        "recall_identifiable": None if not math.isfinite(s.recall_identifiable) else round(s.recall_identifiable, 4),
        "median_translation_error_m": None if not math.isfinite(s.median_translation_error_m)
        else round(s.median_translation_error_m, 5),
        "median_rotation_error_deg": None if not math.isfinite(s.median_rotation_error_deg)
        else round(s.median_rotation_error_deg, 4),
        # The true poses' errors against their own covariances (reloc.matching.covariance).
        "covariance": {"checked": s.covariance_checked,
                       "within_95": None if not math.isfinite(s.within_95) else round(s.within_95, 4),
                       "median_sigma_m": None if not math.isfinite(s.median_sigma_m) else round(s.median_sigma_m, 5)},
        "latency_ms": latency,
        "phases_s": {k: round(v, 2) for k, v in phases.items()},
        "numba": {"kernels": info["kernels"], "compiled_cold": info["cold"]},
        "outcomes": [o.to_dict() for o in outcomes],
    }


def format_demo(result: dict) -> str:
    """The demo's figures as text: the results table, then per-stage latency."""
    c = result["counts"]
    pct = (lambda v: "-" if v is None else f"{100 * v:.1f}")
    cm = (lambda v: "-" if v is None else f"{100 * v:.2f}")
    most = result["spec"].get("window_max_frames", 0)
    grown = f" (up to {most} where fewer cannot pin a pose)" if most > result["spec"]["window_frames"] else ""
    lines = [
        f"scene {result['spec']['scene']} ({result['spec']['plane_source']} planes): map of {result['map']['planes']} "
        f"planes from {result['map']['keyframes']} keyframes; {result['queries']['positive']} positive queries "
        f"({result['queries']['ambiguous']} ambiguous), {result['queries']['negative']} negative "
        f"(scene {result['spec']['negative_scene']}), submaps of {result['spec']['window_frames']} frames{grown}",
        "",
        f"{'TP':>4} {'TN':>4} {'FP':>4} {'FN':>4} {'P[%]':>7} {'R[%]':>7} {'ident':>5} {'R_id[%]':>7} "
        f"{'t_err[cm]':>10} {'r_err[deg]':>10}",
        f"{c['TP']:>4} {c['TN']:>4} {c['FP']:>4} {c['FN']:>4} {pct(result['precision']):>7} "
        f"{pct(result['recall']):>7} {result['identifiable']:>5} {pct(result['recall_identifiable']):>7} "
        f"{cm(result['median_translation_error_m']):>10} "
        f"{'-' if result['median_rotation_error_deg'] is None else format(result['median_rotation_error_deg'], '.3f'):>10}",
        "(ident: positives whose true pose the map confirms, R_id the recall over them; the others no search can "
        "answer under the acceptance rules)",
    ]
    cov = result.get("covariance") or {}
    if cov.get("checked"):
        lines.append(f"pose covariance: {round(cov['within_95'] * cov['checked'])} of {cov['checked']} true poses "
                     f"inside its 95 % ellipsoid, translation sigma {1000 * cov['median_sigma_m']:.1f} mm (median)")
    lines += [
        "",
        f"{'stage':<22} {'median[ms]':>10} {'p95[ms]':>9} {'mean[ms]':>9}",
    ]
    for name, v in result["latency_ms"].items():
        if v["median"] is None:
            continue
        lines.append(f"{name:<22} {v['median']:>10.3f} {v['p95']:>9.3f} {v['mean']:>9.3f}")
    ph = result["phases_s"]
    lines.append("")
    lines.append(f"time: compile {ph['compile_s']:.1f} s, map {ph['map_s']:.1f} s, queries {ph['queries_s']:.1f} s, "
                 f"relocalize {ph['relocalize_s']:.1f} s, total {ph['total_s']:.1f} s")
    return "\n".join(lines)
