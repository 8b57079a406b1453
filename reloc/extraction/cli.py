"""``reloc planes INPUT --out planes.jsonl``: plane extraction of a sequence or a point cloud, one JSON line a frame."""

from __future__ import annotations

import click

from reloc.commands.map_cmd import parse_frames, sequence_config

POINT_CLOUD_SUFFIXES = (".ply", ".npy")


def plane_records(planes) -> list[dict]:
    """Plain JSON-able records of a plane set's planes."""
    return [
        {
            "normal": [round(float(x), 9) for x in planes.normals[i]],
            "offset": round(float(planes.offsets[i]), 9),
            "centroid": [round(float(x), 6) for x in planes.centroids[i]],
            "count": int(planes.counts[i]),
            "radius": round(float(planes.radii[i]), 6),
            "area": round(float(planes.areas[i]), 6),
        }
        for i in range(len(planes))
    ]


@click.command("planes")
@click.argument("input_path", metavar="INPUT", type=click.Path(exists=True))
@click.option("--frames", "frames_spec", default=None, metavar="A:B", help="Frames to process (a:b or one index).")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("-o", "--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="JSON Lines output, one line per frame; the resolved config is written beside it.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def planes(input_path, frames_spec, config_path, out_path, quiet):
    """Extract the planes of every frame of INPUT (a sequence folder, a depth PNG, or a .ply/.npy point cloud).

    Each output line holds the planes (normal, offset, centroid, point count, radius, area) in the camera frame
    (the cloud's own frame for a point cloud) and the time each stage took on that frame, in milliseconds. A frame
    that cannot be read or processed gets a line with its error; the others go on.
    """
    import json
    import sys
    from pathlib import Path

    import yaml

    from reloc._numba import warm_up
    from reloc.atomic import atomic_write, atomic_write_text
    from reloc.config import config_as_dict, load_config
    from reloc.extraction import ExtractionParams, PlaneExtractor

    cfg = load_config(config_path)
    params = ExtractionParams.from_config(cfg)
    extractor = PlaneExtractor(params)
    warm_up(("reloc.extraction",))
    src = Path(input_path)
    out = Path(out_path)
    n_ok = n_failed = 0

    def line(record: dict) -> str:
        return json.dumps(record, separators=(",", ":")) + "\n"

    with atomic_write(out, "w") as fh:
        if src.is_file() and src.suffix.lower() in POINT_CLOUD_SUFFIXES:
            from drivers.pointcloud import read_point_cloud

            if frames_spec is not None:
                parse_frames(frames_spec, 1)
            points = read_point_cloud(src)
            res = extractor.extract_points(points)
            fh.write(line({"frame": 0, "source": str(src), "points": int(res.stats["points"]),
                           "planes": plane_records(res.planes),
                           "timings_ms": {k: round(v, 3) for k, v in res.timings_ms.items()}}))
            n_ok = 1
        else:
            from drivers.readers import open_sequence

            seq = open_sequence(src)
            own = sequence_config(cfg, str(src), quiet)
            if own is not cfg:
                cfg = own
                extractor = PlaneExtractor(ExtractionParams.from_config(cfg))
            indices = parse_frames(frames_spec, len(seq))
            it = indices
            if not quiet:
                from reloc.progress import progress_bar

                it = progress_bar(indices, desc="planes", unit="frame", file=sys.stderr)
            for i in it:
                try:
                    frame = seq[i]
                    res = extractor.extract(frame)
                except (ValueError, OSError) as exc:
                    n_failed += 1
                    fh.write(line({"frame": int(i), "error": str(exc)}))
                    continue
                n_ok += 1
                fh.write(line({
                    "frame": int(i), "seq": int(frame.seq), "stamp_ns": int(frame.stamp_ns),
                    "points": int(res.stats["points"]), "planes": plane_records(res.planes),
                    "timings_ms": {k: round(v, 3) for k, v in res.timings_ms.items()},
                }))
    atomic_write_text(out.with_name(out.stem + ".config.yaml"), yaml.safe_dump(config_as_dict(cfg), sort_keys=False))
    click.echo(f"{out}: {n_ok} frame(s)" + (f", {n_failed} failed (see their error lines)" if n_failed else ""),
               err=True)
    if n_failed and not n_ok:
        raise click.ClickException(f"every frame failed ({n_failed}); their errors are in {out}")
