"""``reloc eval [--ablation]``: the paper's evaluation (Table 1, and Table 3 with --ablation) on the simulator."""

from __future__ import annotations

import click


@click.command("eval")
@click.option("--scenes", default=None, metavar="A,B,...",
              help="Scenes (default: living_room, office, apartment, corridor, meeting_rooms, symmetric_room).")
@click.option("--source", type=click.Choice(["extraction", "oracle"]), default="extraction", show_default=True,
              help="Planes from extraction, or the simulator's ground truth (isolates matching errors).")
@click.option("--queries", type=click.IntRange(min=1), default=10, show_default=True,
              help="Positive queries per trajectory kind (robot-like and hand-held) and scene.")
@click.option("--negatives", type=click.IntRange(min=0), default=20, show_default=True,
              help="Negative queries per scene (taken from the other scenes; the paper uses 20).")
@click.option("--window", type=click.IntRange(min=1), default=40, show_default=True, help="Frames per submap.")
@click.option("--max-window", type=click.IntRange(min=0), default=None,
              help="A submap that cannot pin a pose grows back in time up to this many frames (0 = windows do not "
                   "grow; default 3 x --window, with --quick 0).")
@click.option("--map-frames", type=click.IntRange(min=50), default=3000, show_default=True,
              help="Frames of each mapping trajectory (a robot tour and a hand-held walk).")
# The names of sim.trajectories.TOURS and the suite's SUITE_MAP_TOUR, written out: the CLI imports no simulator
# before a command runs.
@click.option("--map-tour", type=click.Choice(["random", "rooms"]), default="rooms", show_default=True,
              help="Where the mapping trajectories go: every room entered in turn (a mapping run that leaves no "
                   "room out; the suite's since 2026-11-29), or shortest paths to random places (the suite's "
                   "before, and of the suites saved then).")
@click.option("--noise", type=click.Choice(["none", "stereo", "kinect", "tof"]), default="kinect", show_default=True,
              help="Depth noise of the simulated camera: stereo is an OAK-D class camera at its 640 x 400, the "
                   "others a Kinect-like camera at 320 x 240 (160 x 120 with --quick), as in "
                   "benchmarks/reloc_accuracy.py.")
@click.option("--query-seed", type=int, default=None,
              help="Seed of the query trajectories and their noise (default: the suite's, 101). Another value is a "
                   "replicate of the suite on views no default was tuned on (docs/BENCHMARKS.md, held-out "
                   "replicates).")
@click.option("--map-seed", type=int, default=None,
              help="Seed of the mapping trajectories and their noise (default: the suite's, 1).")
@click.option("--ablation", is_flag=True,
              help="Table 3: Ours and each switch off (VR-NE, VR-NM, VR-NI, VR-NG, VR-NP, VR-NO, VR-NS).")
@click.option("--quick", is_flag=True, help="A small run: two scenes, 4 queries per kind, 6 negatives, short maps.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Write the tables and every query's outcome as JSON.")
@click.option("--save-prepared", type=click.Path(file_okay=False), default=None,
              help="Also save the suite's maps and query submaps in this directory (.npz and JSON, 8-15 MB for the "
                   "full suite), to evaluate them again with --prepared.")
@click.option("--prepared", "prepared_dir", type=click.Path(file_okay=False), default=None,
              help="Load the maps and queries saved by --save-prepared instead of building them (seconds instead "
                   "of minutes): for trying matching settings of the config. The suite's options and every "
                   "extraction and fusion parameter must be those it was saved with.")
@click.option("--explain", "explain", multiple=True, metavar="QUERY",
              help="Instead of the table: why this query (as the outcomes name it, e.g. office/robot/3) came out as "
                   "it did, in its own scene's map or in --explain-map's (repeatable; fast with --prepared).")
@click.option("--explain-map", default=None, metavar="SCENE",
              help="With --explain: the scene whose map the query is relocalized in (a negative, when not the "
                   "query's own).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def eval_cmd(scenes, source, queries, negatives, window, max_window, map_frames, map_tour, noise, query_seed, map_seed,
             ablation, quick, config_path, json_path, save_prepared, prepared_dir, explain, explain_map, quiet):
    """Relocalization accuracy like the paper's Table 1 (per scene: TP, TN, FP, FN, P, R, median pose errors, time).

    Positives come from trajectories of each scene that were not used to build its map; negatives from the other
    scenes. A positive within 0.25 m and 5 deg is TP, with a wrong pose FP, rejected FN; a negative rejected is TN,
    accepted FP. Positives whose view repeats elsewhere in the scene (identical rooms, symmetric room) must be
    rejected: a rejection counts as TN, any pose as FP. Times are per relocalization (extraction and submap
    building reported apart).

    Building the maps and queries is the slow part; --save-prepared keeps them and --prepared evaluates them again
    with another config's matching settings (its extraction and fusion settings must be the saved ones; code
    changed since the save is not detected).
    """
    import json
    from dataclasses import asdict, replace

    from reloc._numba import warm_up
    from reloc.atomic import atomic_write_text
    from reloc.config import load_config
    from reloc.evaluation.metrics import format_table, summarize
    from reloc.evaluation.prepared_io import PreparedSuiteError, built_with, load_prepared, mismatch
    from reloc.evaluation.prepared_io import save_prepared as save_prepared_suite
    from reloc.evaluation.suite import SCENES, prepare_suite, quick_spec, run_ablation, sensor_spec, suite_spec
    from reloc.mapping import MappingParams
    from reloc.matching import ABLATIONS, MatchingParams
    from reloc.progress import progress_bar

    if ablation and explain:
        raise click.UsageError("--explain works without --ablation only")
    if explain_map and not explain:
        raise click.UsageError("--explain-map goes with --explain")
    if explain and json_path:
        raise click.UsageError("--explain prints an account, not the table: --json goes without it")
    if ablation and (save_prepared or prepared_dir):
        raise click.UsageError("--save-prepared and --prepared work without --ablation only (its VR-NE and VR-NM "
                               "rows need maps and queries of their own)")
    cfg = load_config(config_path)
    names = tuple(s.strip() for s in scenes.split(",")) if scenes else SCENES
    unknown = [s for s in names if s not in SCENES + ("random", "building")]
    if unknown:
        raise click.BadParameter(f"unknown scene(s) {unknown}; expected some of {', '.join(SCENES)}",
                                 param_hint="--scenes")
    if max_window and max_window < window:
        raise click.BadParameter(f"expected 0 or at least --window ({window}), got {max_window}",
                                 param_hint="--max-window")
    if quick:
        spec = sensor_spec(quick_spec(plane_source=source), noise)
        if scenes:
            spec = replace(spec, scenes=names)
        if max_window is not None:
            spec = replace(spec, window_max_frames=max_window)
        spec = replace(spec, map_tour=map_tour)
    else:
        # The suite of benchmarks/reloc_accuracy.py, whose figures docs/BENCHMARKS.md records.
        spec = suite_spec(noise, plane_source=source, scenes=names, queries=queries, negatives=negatives,
                          window=window, max_window=max_window, map_frames=map_frames, map_tour=map_tour)
    seeds = {k: v for k, v in (("query_seed", query_seed), ("map_seed", map_seed)) if v is not None}
    spec = replace(spec, **seeds)
    extraction = None
    if source == "extraction":
        from reloc.extraction import ExtractionParams

        extraction = ExtractionParams.from_config(cfg)
    matching, mapping = MatchingParams.from_config(cfg), MappingParams.from_config(cfg)
    warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline"), quiet=quiet)
    n_queries = len(spec.scenes) * (len(spec.query_kinds) * spec.queries_per_kind + spec.negatives_per_scene)
    variants = ABLATIONS if ablation else ("Ours",)
    bar = progress_bar(total=n_queries * len(variants), desc="eval", unit="query", disable=quiet, leave=False)

    def progress(n, description):
        # Preparation steps say "scene: map" / "scene: queries"; every relocalized query counts one.
        if description:
            bar.set_description(description)
            if n and not description.endswith((": map", ": queries")):
                bar.update(n)

    params = built_with(spec, extraction, mapping)
    loaded = None
    if prepared_dir:
        try:
            loaded, meta = load_prepared(prepared_dir)
        except PreparedSuiteError as exc:
            raise click.BadParameter(str(exc), param_hint="--prepared") from None
        if explain:
            # Explaining a saved suite: its own scenes, sensor and seeds, whatever the suite options say; only the
            # extraction and fusion settings of the config must be the ones it was built with.
            spec = loaded.spec
            params = built_with(spec, extraction, mapping)
        problems = mismatch(loaded, meta, spec, params)
        if problems:
            raise click.BadParameter(f"{prepared_dir} holds another suite than this command asks for: "
                                     + "; ".join(problems), param_hint="--prepared")
    try:
        if ablation:
            results = run_ablation(spec, variants, matching, mapping, extraction=extraction, progress=progress)
        else:
            if loaded is None:
                loaded = prepare_suite(spec, mapping, extraction=extraction, progress=progress)
            if save_prepared:
                saved = save_prepared_suite(save_prepared, loaded, {"params": params, "program": "reloc eval"})
            if not explain:
                results = {"Ours": loaded.evaluate(matching, progress)}
    finally:
        bar.close()
    if save_prepared:
        click.echo(f"saved the prepared suite to {saved.parent}")
    if explain:
        _explain(loaded, explain, explain_map, matching)
        return

    out = {"spec": asdict(spec), "tables": {}, "outcomes": {}}
    if not ablation:
        rows = results["Ours"]
        summaries = [r.summary() for r in rows] + [summarize("all", [o for r in rows for o in r.outcomes])]
        click.echo(format_table(summaries))
        click.echo("")
        for r in rows:
            click.echo(f"{r.scene}: map of {r.map_planes} planes built in {r.map_seconds:.1f} s")
        out["tables"]["Ours"] = [s.to_dict() for s in summaries]
        out["outcomes"]["Ours"] = [o.to_dict() for r in rows for o in r.outcomes]
    else:
        summaries = [summarize(v, [o for r in rows for o in r.outcomes]) for v, rows in results.items()]
        click.echo(format_table(summaries, first_column="method"))
        if source == "oracle":
            click.echo("(oracle planes: VR-NE and VR-NM switch extraction features off, so they equal Ours here)")
        for v, rows in results.items():
            out["tables"][v] = [s.to_dict() for s in [r.summary() for r in rows]]
            out["outcomes"][v] = [o.to_dict() for r in rows for o in r.outcomes]
        out["tables"]["by_method"] = [s.to_dict() for s in summaries]
    if json_path:
        atomic_write_text(json_path, json.dumps(out, indent=1) + "\n")
        click.echo(f"wrote {json_path}")


def _explain(prepared, names, map_scene, matching) -> None:
    """Print :func:`reloc.evaluation.explain.explain_query` for each query of ``names`` in ``prepared``."""
    from reloc.evaluation.ambiguity import scene_symmetries
    from reloc.evaluation.explain import explain_query

    if map_scene is not None and map_scene not in prepared.maps:
        raise click.BadParameter(f"no map of {map_scene!r} in this suite; it has {', '.join(prepared.maps)}",
                                 param_hint="--explain-map")
    for name in names:
        try:
            q = prepared.find_query(name)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint="--explain") from None
        scene = map_scene or q.scene
        truth = q.T_world_cam if scene == q.scene else None
        if truth is None:
            how = " (a negative: any pose is wrong)"
        else:
            how = ", labelled ambiguous (any pose counts as wrong)" if q.ambiguous else ""
        click.echo(f"== {name} in the map of {scene}{how}")
        symmetries = scene_symmetries(scene) if truth is not None else []
        click.echo(explain_query(prepared.relocalizer(scene, matching), q.submap, truth, symmetries=symmetries))
