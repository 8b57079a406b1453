"""``reloc demo``: the main job (see :mod:`reloc.demo`)."""

from __future__ import annotations

import click


@click.command("demo")
@click.option("--scene", default="living_room", show_default=True, help="Scene to map and relocalize in.")
@click.option("--negative-scene", default="office", show_default=True, help="Scene the negative queries come from.")
@click.option("--source", type=click.Choice(["extraction", "oracle"]), default="extraction", show_default=True,
              help="Planes from extraction (the real pipeline) or the simulator's ground truth.")
@click.option("--queries", type=click.IntRange(min=1), default=5, show_default=True,
              help="Positive queries per trajectory kind (robot-like and hand-held).")
@click.option("--negatives", type=click.IntRange(min=0), default=10, show_default=True, help="Negative queries.")
@click.option("--noise", type=click.Choice(["kinect", "stereo", "tof", "none"]), default="kinect", show_default=True,
              help="Depth noise of the simulated camera: a Kinect-like camera at 320 x 240 (kinect, tof, none), or "
                   "for stereo an OAK-D class camera at its 640 x 400, as in reloc eval.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True)
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the figures (and every query's outcome) as JSON.")
@click.option("--plots", "plots_dir", type=click.Path(file_okay=False), default=None,
              help="Also save pictures into this directory: a frame's planes, the map with a relocalized submap, "
                   "all queries on the map, precision/recall bars, latency histograms (needs pip install -e "
                   "'.[viz]').")
@click.option("--rerun", "rerun_path", type=click.Path(dir_okay=False), default=None,
              help="Also write a Rerun recording (.rrd: the map, a frame with its planes, each query's submap at its "
                   "estimated pose and the truth); needs pip install rerun-sdk.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def demo(scene, negative_scene, source, queries, negatives, noise, seed, config_path, json_path, plots_dir, rerun_path,
         quiet):
    """Simulate a scene, build its map, relocalize positive and negative queries, print the results table.

    Prints precision, recall, median pose errors and per-stage latency; the first run compiles the numba kernels
    (cached for later runs).
    """
    import json

    from reloc.atomic import atomic_write_text
    from reloc.config import load_config
    from reloc.demo import DemoSpec, format_demo, run_demo
    from reloc.evaluation.suite import sensor_spec
    from reloc.progress import progress_bar

    if plots_dir:  # matplotlib checked before the long run, not after it
        from reloc.viz._mpl import require_matplotlib

        try:
            require_matplotlib()
        except ImportError as exc:
            raise click.ClickException(str(exc)) from None
    if rerun_path:
        from reloc.viz.rerun_log import require_rerun

        if not rerun_path.endswith(".rrd"):
            raise click.BadParameter(f"expected a .rrd file name, got {rerun_path!r}", param_hint="--rerun")
        try:
            require_rerun()
        except ImportError as exc:
            raise click.ClickException(str(exc)) from None
    cfg = load_config(config_path)
    spec = sensor_spec(DemoSpec(scene=scene, negative_scene=negative_scene, plane_source=source,
                                queries_per_kind=queries, negatives=negatives, seed=seed), noise)
    bar = progress_bar(total=4, desc="demo", disable=quiet, leave=False, bar_format="{desc}: {n}/{total}{postfix}")
    state = {"last": None}

    def progress(step, done, total):
        if step != state["last"]:
            if state["last"] is not None:
                bar.update(1)
            state["last"] = step
        bar.set_postfix_str(f"{step} {done}/{total}")

    try:
        kept: dict = {}
        result = run_demo(spec, cfg, progress=progress, keep=kept if (plots_dir or rerun_path) else None)
    finally:
        bar.close()
    click.echo(format_demo(result))
    if json_path:
        atomic_write_text(json_path, json.dumps(result, indent=1) + "\n")
        click.echo(f"wrote {json_path}")
    if plots_dir:
        from reloc.viz.demo_plots import save_demo_plots

        for path in save_demo_plots(result, kept, plots_dir):
            click.echo(f"wrote {path}")
    if rerun_path:
        from reloc.viz.demo_plots import save_demo_rerun

        click.echo(f"wrote {save_demo_rerun(result, kept, rerun_path)} (open it with: rerun {rerun_path})")
