"""``reloc record`` and ``reloc devices``: recording any frame source, listing attached cameras."""

from __future__ import annotations

import click

from drivers.source import SOURCE_SPECS


def _source_options(pairs: tuple[str, ...]) -> dict:
    """``KEY=VALUE`` pairs -> constructor keywords; values are YAML scalars (``n_frames=50``, ``loop=true``,
    ``rate_hz=1e3``)."""
    from reloc.config import load_yaml

    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.isidentifier():
            raise click.BadParameter(f"expected KEY=VALUE, got {pair!r}", param_hint="--option")
        out[key] = load_yaml(value) if value else ""
    return out


@click.command("record")
@click.option("--camera", "spec", required=True, help=f"Frame source: {SOURCE_SPECS}.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False), help="Output folder (TUM layout).")
@click.option("--frames", "n_frames", type=click.IntRange(min=1), default=None, help="Stop after N frames.")
@click.option("--duration", "duration_s", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Stop after S seconds.")
@click.option("--rate", default=None, help="Pacing of sim/replay/rosbag sources: recorded, fast (default) or a rate in Hz.")
@click.option("--config", "config_file", type=click.Path(dir_okay=False, exists=True), default=None,
              help="Config YAML (its oak section sets up OAK cameras).")
@click.option("-o", "--option", "options", multiple=True, metavar="KEY=VALUE",
              help="Extra source parameter, repeatable (sim: trajectory=handheld noise=kinect seed=3; replay: loop=true).")
@click.option("--overwrite", is_flag=True, help="Replace a sequence already in --out.")
def record_cmd(spec: str, out_dir: str, n_frames: int | None, duration_s: float | None, rate: str | None,
               config_file: str | None, options: tuple[str, ...], overwrite: bool) -> None:
    """Record depth frames from a camera, the simulator or a replay into the TUM RGB-D layout.

    The result replays, maps and evaluates with the same commands as a dataset (``--camera replay:OUT``).
    Ctrl-C stops the recording cleanly: what was written is a valid sequence.
    """
    from drivers.source import SourceError

    try:
        _record(spec, out_dir, n_frames, duration_s, rate, config_file, options, overwrite)
    except SourceError as exc:
        raise click.ClickException(str(exc)) from None


def _record(spec, out_dir, n_frames, duration_s, rate, config_file, options, overwrite) -> None:
    from drivers.recorder import record
    from drivers.source import open_source

    kwargs = _source_options(options)
    kind = spec.partition(":")[0]
    if kind in ("sim", "replay", "rosbag"):
        kwargs.setdefault("rate", rate or "fast")
    elif rate is not None:
        raise click.BadParameter("--rate applies to sim, replay and rosbag sources only", param_hint="--rate")
    if kind == "sim" and n_frames is not None:
        kwargs.setdefault("n_frames", n_frames)
    if config_file is not None and kind != "oak":
        raise click.BadParameter(f"--config sets up OAK cameras (its oak section); a {kind} source takes its "
                                 "settings from -o KEY=VALUE", param_hint="--config")
    if kind == "oak":
        from drivers.oak import oak_kwargs_from_config
        from reloc.config import load_config

        kwargs = {**oak_kwargs_from_config(load_config(config_file)), **kwargs}
    extra = {}
    with open_source(spec, **kwargs) as source:
        scene = getattr(source, "scene", None)
        if scene is not None:
            extra.update(_scene_files(scene))
        sequence = getattr(source, "sequence", None)
        if sequence is not None:
            extra.update(_sequence_files(sequence.path))
        click.echo(f"recording {source.name} ({source.intrinsics.width}x{source.intrinsics.height}) to {out_dir}",
                   err=True)
        try:
            summary = record(source, out_dir, n_frames=n_frames, duration_s=duration_s, overwrite=overwrite,
                             extra_files=extra, progress=True)
        except KeyboardInterrupt:
            click.echo("interrupted: the frames written so far form a valid sequence", err=True)
            return
    click.echo(summary.text())


def _scene_files(scene) -> dict[str, str]:
    """``planes.json`` of a simulated scene (the simulator's ground-truth planes), when its writer is available."""
    import json

    try:
        from sim.writer import planes_json
    except ImportError:
        return {}
    return {"planes.json": json.dumps(planes_json(scene), indent=1) + "\n"}


def _sequence_files(path) -> dict[str, str]:
    """The simulator's ``planes.json`` (ground-truth planes) and ``sim.json`` (how it was made) of a replayed
    sequence, when it has them: a recording of a simulated sequence keeps its ground truth."""
    from pathlib import Path

    out = {}
    for name in ("planes.json", "sim.json"):
        f = Path(path) / name
        if f.is_file():
            out[name] = f.read_text()
    return out


@click.command("devices")
@click.option("--timeout", "timeout_s", type=click.FloatRange(min=0.1), default=2.0, show_default=True,
              help="How long to search for devices.")
def devices_cmd(timeout_s: float) -> None:
    """List attached OAK cameras (needs the `oak` extra: pip install 'voxelplane-reloc[oak]')."""
    from drivers.oak import list_devices
    from drivers.source import SourceError

    try:
        found = list_devices(timeout_s=timeout_s)
    except SourceError as exc:
        raise click.ClickException(str(exc)) from None
    if not found:
        click.echo(f"no OAK device found (searched {timeout_s:g} s)")
        return
    for dev in found:
        click.echo("  ".join(f"{k}={v}" for k, v in dev.items()))
