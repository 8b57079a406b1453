"""``reloc plot map|frame|eval|latency``: PNG pictures from the files other commands write.

- ``map MAP``: the map from above; with ``--results`` every query of ``reloc locate`` (ground truth from
  ``--truth SEQ``); with ``--submap SEQ --frame I`` one query's submap at its estimated pose (Fig. 4 of the paper).
- ``frame SEQ --index I``: a depth frame with its extracted planes and normals.
- ``eval FILE.json``: precision and recall per scene / source / ablation (``reloc eval --json``,
  ``benchmarks/reloc_accuracy.py``, ``reloc demo --json``).
- ``latency FILE``: latency histograms per stage (``reloc profile --json``, ``reloc run --summary``, ``reloc locate``
  results, ``reloc eval --json``, ``reloc demo --json``).
matplotlib (the ``viz`` extra) is imported only when a picture is made.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from reloc.commands.map_cmd import SOURCES, parse_frames, sequence_config, sequence_plane_source

INSTALL_HINT = "pip install -e '.[viz]'"


def need_matplotlib() -> None:
    """Raise a ClickException naming the extra to install when matplotlib is missing."""
    try:
        from reloc.viz._mpl import require_matplotlib

        require_matplotlib()
    except ImportError:
        raise click.ClickException(
            f"pictures need matplotlib, which is not installed: {INSTALL_HINT} (the viz extra)") from None


def read_json(path: str, what: str):
    """A JSON document, or (for .jsonl files) the list of its lines; ValueError naming the file and the problem."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the {what} ({exc})") from None
    if not text.strip():
        raise ValueError(f"{path}: empty file, expected the {what}")
    try:
        if p.suffix.lower() == ".jsonl":
            return [json.loads(line) for line in text.splitlines() if line.strip()]
        return json.loads(text)
    except ValueError as exc:
        raise ValueError(f"{path}: not JSON ({exc}); expected the {what}") from None


def _size_options(width: int, height: int | None):
    def deco(f):
        f = click.option("--height", type=click.IntRange(min=100), default=height, show_default=height is not None,
                         help="PNG height in pixels" + ("" if height else " (default: sized to the content)") + ".")(f)
        f = click.option("--width", type=click.IntRange(min=100), default=width, show_default=True,
                         help="PNG width in pixels.")(f)
        f = click.option("--title", default=None, help="Title of the picture.")(f)
        f = click.option("-o", "--out", "out_path", required=True, type=click.Path(dir_okay=False),
                         help="PNG file to write.")(f)
        return f

    return deco


def _check_png(out_path: str) -> None:
    if Path(out_path).suffix.lower() != ".png":
        raise click.BadParameter(f"expected a .png file name, got {out_path!r}", param_hint="-o/--out")


@click.group("plot")
def plot() -> None:
    """Pictures (PNG of an exact pixel size) from maps, results, evaluations and profiles.

    Needs matplotlib: pip install -e '.[viz]'.
    """


@plot.command("map")
@click.argument("map_path", metavar="MAP", type=click.Path(dir_okay=False))
@click.option("--results", "results_path", type=click.Path(dir_okay=False), default=None,
              help="reloc locate results (JSON Lines): every query's estimated camera, coloured by outcome.")
@click.option("--truth", "truth_seq", type=click.Path(exists=True), default=None,
              help="The queries' sequence: its poses are the ground truth (its world frame must be the map frame).")
@click.option("--submap", "submap_seq", type=click.Path(exists=True), default=None,
              help="Sequence to build one query's submap from (with --frame), drawn at its estimated pose.")
@click.option("--frame", "query_frame", type=int, default=None, help="The query frame of --submap.")
@click.option("--window", type=click.IntRange(min=1), default=None,
              help="Frames fused into the submap (config mapping.submap_window_frames by default), as reloc locate.")
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True,
              help="Frames between the frames of the submap's window.")
@click.option("--source", type=click.Choice(SOURCES), default="extraction", show_default=True,
              help="Planes of the submap from extraction or the simulator's ground truth.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@_size_options(1100, 900)
def plot_map(map_path, results_path, truth_seq, submap_seq, query_frame, window, stride, source, config_path,
             out_path, title, width, height):
    """The map MAP from above (walls dark, floors light), with relocalization results or one relocalized submap.

    \b
    reloc plot map map.npz -o map.png
    reloc plot map map.npz --results results.jsonl --truth SEQ -o results.png
    reloc plot map map.npz --submap SEQ --frame 120 [--results results.jsonl] -o submap.png
    With --submap the estimate comes from the --results line of that frame, or from relocalizing the submap now.
    """
    import numpy as np

    from reloc.mapping import load_map

    _check_png(out_path)
    if (submap_seq is None) != (query_frame is None):
        raise click.UsageError("--submap SEQ and --frame I go together")
    need_matplotlib()
    plane_map = load_map(map_path)
    from drivers.readers import open_sequence

    if submap_seq is None:
        if results_path is None:
            from reloc.viz.maps import plot_map_topdown

            out = plot_map_topdown(plane_map.planes, out_path, title=title or f"{Path(map_path).name} from above",
                                   width_px=width, height_px=height)
            click.echo(f"wrote {out}")
            return
        from reloc.viz.results import plot_reloc_results, read_results

        records = read_results(results_path)
        truth = {}
        if truth_seq is not None:
            seq = open_sequence(truth_seq)
            has = seq.has_pose
            for r in records:
                i = int(r["frame"])
                if not 0 <= i < len(seq):
                    raise ValueError(f"{results_path}: frame {i} is not in {truth_seq} ({len(seq)} frames); "
                                     "--truth must be the sequence the queries came from")
                if has[i]:
                    truth[i] = seq.T_world_cam[i]
        out = plot_reloc_results(plane_map.planes, records, out_path, truth=truth,
                                 title=title or f"{Path(results_path).name} on {Path(map_path).name}",
                                 width_px=width, height_px=height)
        click.echo(f"wrote {out}")
        return

    # One query: its submap, its estimate (results file or relocalize now), its ground truth.
    from reloc.config import load_config
    from reloc.mapping import MappingParams, build_submap
    from reloc.viz.maps import plot_map_topdown

    cfg = sequence_config(load_config(config_path), submap_seq, quiet=True)  # its noise law, as reloc locate
    mapping = MappingParams.from_config(cfg)
    seq = open_sequence(submap_seq)
    q = parse_frames(str(query_frame), len(seq), "--frame")[0]
    k = window or mapping.submap_window_frames
    idx = [i for i in range(q - stride * (k - 1), q + 1, stride) if i >= 0]
    has = seq.has_pose
    if not has[q]:
        idx = [q]  # no odometry for the query frame: a single-frame submap, as reloc locate
    else:
        idx = [i for i in idx if has[i]]
    plane_source = sequence_plane_source(submap_seq, source, cfg)
    frames = [seq[i] for i in idx]
    submap = build_submap([plane_source(f) for f in frames],
                          [f.T_world_cam for f in frames] if len(frames) > 1 else None, mapping)
    if results_path is not None:
        from reloc.viz.results import read_results

        record = next((r for r in read_results(results_path) if int(r["frame"]) == q), None)
        if record is None:
            raise ValueError(f"{results_path}: no line for frame {q}")
        status, T_est, reason = record["status"], record.get("T_map_cam"), record.get("reason", "")
    else:
        from reloc._numba import warm_up
        from reloc.matching import MatchingParams, Relocalizer

        warm_up(("reloc.matching._kernels",), quiet=True)
        res = Relocalizer(plane_map, MatchingParams.from_config(cfg)).locate(submap)
        status, T_est, reason = res.status, res.T_map_cam, res.reason
    T_gt = seq.T_world_cam[q] if has[q] else None
    if truth_seq is not None:
        tseq = open_sequence(truth_seq)
        T_gt = tseq.T_world_cam[q] if q < len(tseq) and tseq.has_pose[q] else T_gt
    relocalized = status == "relocalized"
    head = title or f"frame {q} of {Path(submap_seq).name} ({len(idx)} frames) on {Path(map_path).name}"
    if not relocalized:
        import textwrap

        head += f"\n{status}" + (f": {reason}" if reason else "")
        head = "\n".join(textwrap.wrap(head, width=max(40, width // 9), replace_whitespace=False))
    out = plot_map_topdown(plane_map.planes, out_path, submap=submap,
                           T_map_cam=np.asarray(T_est, dtype=float) if relocalized else None,
                           T_map_cam_gt=T_gt, relocalized=relocalized, title=head, width_px=width, height_px=height)
    click.echo(f"wrote {out} ({status})")


@plot.command("frame")
@click.argument("seq", type=click.Path(exists=True))
@click.option("--index", "index", type=int, required=True, help="Frame index (negative: from the end).")
@click.option("--source", type=click.Choice(SOURCES), default="extraction", show_default=True,
              help="Planes from extraction or the simulator's ground truth (sequences written by reloc sim).")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("--map", "map_path", type=click.Path(dir_okay=False), default=None,
              help="Extract with the configuration a map was built with (recorded in the map file), not --config.")
@_size_options(1500, 560)
def plot_frame(seq, index, source, config_path, map_path, out_path, title, width, height):
    """Frame INDEX of SEQ: its depth, and its planes coloured with their normals (camera frame)."""
    from drivers.readers import open_sequence
    from reloc.config import config_from_dict, load_config
    from reloc.viz.frames import plot_frame_planes

    _check_png(out_path)
    if map_path and config_path:
        raise click.UsageError("give --config or --map (the map's recorded config), not both")
    need_matplotlib()
    if map_path:
        from reloc.mapping import load_map

        recorded = load_map(map_path).meta.get("config")
        if not isinstance(recorded, dict):
            raise ValueError(f"{map_path}: the map records no config (meta.config); use --config")
        cfg = config_from_dict(recorded, source=f"{map_path}: meta.config")
    else:
        cfg = sequence_config(load_config(config_path), seq, quiet=True)  # its noise law, as reloc extract
    sequence = open_sequence(seq)
    i = parse_frames(str(index), len(sequence), "--index")[0]
    frame = sequence[i]
    planes = sequence_plane_source(seq, source, cfg)(frame)
    out = plot_frame_planes(frame, planes, out_path, title=title, width_px=width, height_px=height)
    click.echo(f"wrote {out} ({len(planes)} planes, {source})")


@plot.command("eval")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--source", "source_key", default=None,
              help="benchmarks/reloc_accuracy.py JSON: the plane source whose scenes to show (default: the first "
                   ".../ours).")
@_size_options(1300, None)
def plot_eval(file, source_key, out_path, title, width, height):
    """Precision and recall per scene, per source and per ablation, with the outcome counts, from FILE (JSON of
    reloc eval --json, reloc eval --ablation --json, benchmarks/reloc_accuracy.py or reloc demo --json)."""
    from reloc.viz.evaluation import eval_panels, plot_eval_bars

    _check_png(out_path)
    need_matplotlib()
    data = read_json(file, "evaluation JSON")
    try:
        panels = eval_panels(data, source_key)
    except ValueError as exc:
        raise ValueError(f"{file}: {exc}") from None
    out = plot_eval_bars(panels, out_path, title=title, width_px=width, height_px=height)
    click.echo(f"wrote {out} ({len(panels)} panels)")


@plot.command("latency")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--stages", default=None, metavar="A,B,...", help="Stages to draw, in this order (default: the "
              "costliest).")
@click.option("--max-stages", type=click.IntRange(min=1), default=12, show_default=True,
              help="At most this many stages (the costliest by total time) when --stages is not given.")
@click.option("--table8", is_flag=True, help="reloc profile JSON: the grouped rows of the paper's Table 8 (single "
              "frame, local observation, localization, pose likelihood, total) instead of every stage.")
@_size_options(1400, None)
def plot_latency_cmd(file, stages, max_stages, table8, out_path, title, width, height):
    """Latency histograms per stage (p50, p95, p99 marked) from FILE: reloc profile --json, reloc run --summary,
    reloc locate results (.jsonl), reloc eval --json or reloc demo --json."""
    from reloc.viz.latency import latency_data, plot_latency

    _check_png(out_path)
    need_matplotlib()
    data = read_json(file, "profile or timings")
    try:
        lat = latency_data(data, table8=table8)
        if table8 and not stages:
            stages = ",".join(k for k in data["table8"] if k != "total") + ",total"
        names = [s.strip() for s in stages.split(",") if s.strip()] if stages else None
        out = plot_latency(lat, out_path, stages=names, max_stages=max_stages,
                           title=title or f"latency per stage: {Path(file).name} ({lat.source})",
                           width_px=width, height_px=height)
    except ValueError as exc:
        raise ValueError(f"{file}: {exc}") from None
    click.echo(f"wrote {out}")
