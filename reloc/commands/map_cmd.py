"""``reloc map build SEQ -o map.npz`` and ``reloc map info map.npz``."""

from __future__ import annotations

import click

SOURCES = ("extraction", "oracle")


def parse_frames(spec: str | None, n: int, param_hint: str = "--frames") -> range:
    """Frame indices of ``a:b`` (Python slice semantics, either end optional, negative from the end) or ``i``.

    A range that selects no frame (``5:2``, or past the end) is an error naming ``param_hint`` (the option it came
    from), not an empty run."""
    if spec is None:
        return range(n)
    text = spec.strip()
    try:
        if ":" in text:
            a, _, b = text.partition(":")
            picked = range(n)[slice(int(a) if a.strip() else None, int(b) if b.strip() else None)]
            if len(picked) == 0:
                raise click.BadParameter(f"{spec!r} selects none of the {n} frames (0:{n})", param_hint=param_hint)
            return picked
        i = int(text)
    except ValueError:
        raise click.BadParameter(f"expected a:b or an index, got {spec!r}", param_hint=param_hint) from None
    if not -n <= i < n:
        raise click.BadParameter(f"index {i} outside the {n} frames", param_hint=param_hint)
    return range(n)[i: i + 1 or None]


def sequence_config(cfg, seq_path: str, quiet: bool = False):
    """``cfg`` with the depth noise law the sequence at ``seq_path`` stored (``reloc record``, ``reloc sim``), unless
    the config names one itself (:func:`reloc.config.with_noise_law`); says so on stderr unless ``quiet``."""
    from drivers.readers import read_noise_law
    from reloc.config import with_noise_law

    cfg, note = with_noise_law(cfg, read_noise_law(seq_path), seq_path)
    if note and not quiet:
        click.echo(note, err=True)
    return cfg


def sequence_plane_source(seq_path: str, kind: str, cfg):
    """``frame -> PlaneSet`` for frames of the sequence at ``seq_path``: extraction with the config's parameters, or
    (``oracle``) the simulator's ground truth, for sequences written by ``reloc sim`` (their ``sim.json`` names the
    scene)."""
    import json
    from pathlib import Path

    if kind == "extraction":
        from reloc.extraction import ExtractionParams
        from reloc.mapping import extraction_source

        return extraction_source(ExtractionParams.from_config(cfg))
    meta_path = Path(seq_path) / "sim.json"
    if not meta_path.is_file():
        raise click.BadParameter(f"{seq_path}: no sim.json, so no ground truth; use --source extraction",
                                 param_hint="--source")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        scene_name, scene_seed = meta["scene"], int(meta.get("scene_seed", 0))
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{meta_path}: cannot read the scene name ({exc})") from None
    from sim.scenes import make_scene

    from reloc.mapping import oracle_source

    return oracle_source(make_scene(scene_name, scene_seed))


def config_sections(cfg, names=("camera", "extraction", "merging", "mapping", "matching", "evaluation")) -> dict:
    from reloc.config import config_as_dict

    d = config_as_dict(cfg)
    return {k: d[k] for k in names if k in d}


@click.group("map")
def map_group() -> None:
    """Build a plane map from a posed sequence, or show what a map file holds."""


@map_group.command("build")
@click.argument("seq", type=click.Path(exists=True))
@click.option("-o", "--out", "out_path", required=True, type=click.Path(dir_okay=False), help="Map file (.npz).")
@click.option("--frames", "frames_spec", default=None, metavar="A:B", help="Frames to use (a:b or one index).")
@click.option("--source", type=click.Choice(SOURCES), default="extraction", show_default=True,
              help="Planes from extraction, or the simulator's ground truth (sequences written by reloc sim).")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def build(seq, out_path, frames_spec, source, config_path, quiet):
    """Build the plane map of the posed sequence SEQ (any layout the reader takes) and write it to --out.

    Keyframes are chosen by motion; their planes are moved into the map frame (the sequence's world frame) and
    fused into one plane per surface; the space their depth rays crossed is kept as known free space. The resolved
    config is written beside the map (OUT.config.yaml) and recorded in its metadata.
    """
    import time
    from pathlib import Path

    import yaml

    from drivers.readers import open_sequence
    from reloc._numba import warm_up
    from reloc.atomic import atomic_write_text
    from reloc.config import load_config
    from reloc.mapping import MappingParams, build_map, save_map
    from reloc.progress import progress_bar

    sequence = open_sequence(seq)
    cfg = sequence_config(load_config(config_path), seq, quiet)
    idx = parse_frames(frames_spec, len(sequence))
    if not sequence.has_pose[list(idx)].any():
        raise click.ClickException(f"{seq}: no frame has a pose; a map needs posed frames (ground truth or odometry)")
    plane_source = sequence_plane_source(seq, source, cfg)
    warm_up(("reloc.mapping._kernels", "reloc.extraction.pipeline") if source == "extraction" else
            ("reloc.mapping._kernels",), quiet=quiet)
    t0 = time.perf_counter()
    with progress_bar(total=len(idx), desc="map", unit="frame", disable=quiet, leave=False) as bar:
        frames = (sequence[i] for i in idx)
        plane_map = build_map(
            frames, plane_source, MappingParams.from_config(cfg), progress=bar.update,
            meta={"source": str(Path(seq).resolve()), "sequence_format": sequence.format, "plane_source": source,
                  "frames": f"{idx.start}:{idx.stop}", "config": config_sections(cfg)},
        )
    out = save_map(out_path, plane_map)
    atomic_write_text(str(out) + ".config.yaml", yaml.safe_dump(config_sections(cfg), sort_keys=False))
    s = plane_map.summary()
    click.echo(
        f"{out}: {s['planes']} planes ({s['horizontal_planes']} horizontal), {s['total_area_m2']} m^2, "
        f"{s['free_space_m3']} m^3 known free space, from {plane_map.meta['keyframe_count']} keyframes of "
        f"{plane_map.meta['frame_count']} frames ({plane_map.meta['frames_without_pose']} without pose, "
        f"{plane_map.meta['frames_failed']} failed) in {time.perf_counter() - t0:.1f} s"
    )
    note = bent_planes_note(s)
    if note:
        click.echo(note)
    need = cfg.evaluation.min_matched_planes
    if s["planes"] < need:
        # Not an error (the file is a valid map), but nothing can be relocalized in it: say why and what helps.
        click.echo(
            f"note: {s['planes']} planes are too few to relocalize in (a pose needs evaluation.min_matched_planes = "
            f"{need}); planes seen in fewer than mapping.min_observations = {cfg.mapping.min_observations} of the "
            f"{plane_map.meta['keyframe_count']} keyframes were dropped: map a longer sequence, or lower "
            "mapping.min_observations or the keyframe thresholds (mapping.keyframe_min_translation_m, "
            "keyframe_min_rotation_deg)", err=True)


def bent_planes_note(summary: dict) -> str | None:
    """What ``reloc map build`` says of planes fused across two surfaces (a door in its niche and the wall, furniture
    and the wall behind it; matching against such a plane tilts poses), from :meth:`PlaneMap.summary`; None if none."""
    from reloc.mapping.plane_map import BENT_FRACTION, BENT_OFF_M

    if not summary["bent_planes"]:
        return None
    return (f"note: {summary['bent_planes']} planes ({summary['bent_area_m2']} m^2) have more than {BENT_FRACTION:.0%} "
            f"of their samples more than {100 * BENT_OFF_M:.0f} cm off them; "
            f"{100 * summary['samples_off_plane_fraction']:.1f}% of all samples are that far (reloc map info shows the "
            "same)")


@map_group.command("info")
@click.argument("map_path", metavar="MAP", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Everything as JSON (metadata with its config, summary).")
def info(map_path, as_json):
    """Show what the map file MAP holds: planes, extent, free space and how it was made."""
    import json

    from reloc.mapping import load_map

    plane_map = load_map(map_path)
    summary = plane_map.summary()
    if as_json:
        click.echo(json.dumps({"file": map_path, "summary": summary, "meta": plane_map.meta}, indent=1))
        return
    meta = {k: v for k, v in plane_map.meta.items() if k != "config"}
    click.echo(f"{map_path}")
    for k, v in summary.items():
        click.echo(f"  {k}: {v}")
    for k in sorted(meta):
        click.echo(f"  {k}: {meta[k]}")
    recorded = plane_map.meta.get("config")
    ex = recorded.get("extraction") if isinstance(recorded, dict) else None
    if isinstance(ex, dict) and isinstance(ex.get("noise_coeff"), (int, float)):
        # The law its planes were extracted with (queries are best extracted with the same camera's law).
        click.echo(f"  depth_noise: {ex.get('noise_model')} {ex['noise_coeff']:.4g}")
