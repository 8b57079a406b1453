"""``reloc locate --map map.npz SEQ [--frames a:b] [--window K] --out results.jsonl``."""

from __future__ import annotations

import click

from reloc.commands.map_cmd import SOURCES, config_sections, parse_frames, sequence_config, sequence_plane_source


@click.command("locate")
@click.argument("seq", type=click.Path(exists=True))
@click.option("--map", "map_path", required=True, type=click.Path(exists=True, dir_okay=False), help="Map file.")
@click.option("-o", "--out", "out_path", required=True, type=click.Path(dir_okay=False), help="JSON Lines output.")
@click.option("--frames", "frames_spec", default=None, metavar="A:B", help="Query frames (a:b or one index).")
@click.option("--window", type=click.IntRange(min=1), default=None,
              help="Frames fused into each submap (config mapping.submap_window_frames by default).")
@click.option("--max-window", type=click.IntRange(min=0), default=None,
              help="A submap that cannot pin a pose grows back in time up to this many frames (config "
                   "mapping.submap_max_window_frames by default; 0 = the window does not grow).")
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True,
              help="Frames between the frames of a window.")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True, help="Query every n-th frame.")
@click.option("--source", type=click.Choice(SOURCES), default="extraction", show_default=True,
              help="Planes from extraction, or the simulator's ground truth (sequences written by reloc sim).")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("--check-poses", is_flag=True,
              help="Also check each query at the sequence's own pose (ground truth in the map's frame): the error "
                   "of the answer, and whether that pose is confirmed as locate would accept it.")
@click.option("--explain", "explain_path", type=click.Path(dir_okay=False), default=None,
              help="Also write to this text file why each query came out as it did: the poses weighed and each "
                   "submap plane's state under them (against the sequence's poses with --check-poses).")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def locate(seq, map_path, out_path, frames_spec, window, max_window, stride, every, source, config_path, check_poses,
           explain_path, quiet):
    """Relocalize frames of SEQ in the map: one JSON line per query frame.

    Each query is a submap of the last --window frames (--stride apart) ending at the query frame, fused with the
    sequence's poses as odometry (only relative poses are used; frames without a pose restart the window; frames
    whose planes disagree with the query frame's are left out), grown back in time up to --max-window frames while
    it cannot pin a pose (too few planes, or too little area along its weakest direction). A line holds the frame
    index, stamp_ns, status, reason, T_map_cam (4x4 nested list, or null), its covariance (6x6: the left
    perturbation in the map frame, translation first, m^2 and rad^2; or null), score, the matched plane count, the
    window's frame count and how many of them the odometry check left out, the counts of every stage and the
    milliseconds of every stage (extraction and submap building included).
    A frame that cannot be read or processed gets a line with status "error"; the others go on.

    With --check-poses (for a sequence whose poses are ground truth in the map's frame, as when the map was built
    from the same or a co-registered run), a line also holds "truth": the answer's translation and rotation error
    against the query frame's pose, and whether that pose is identifiable (``Relocalizer.confirm``: locate with it
    as the only hypothesis accepts it, refined within 0.25 m and 5 deg) or the reason it is not: a view no search
    could answer under the acceptance rules.
    """
    import json
    import time

    import numpy as np
    import yaml

    from drivers.readers import open_sequence
    from reloc._numba import warm_up
    from reloc.atomic import atomic_write_text
    from reloc.config import load_config
    from reloc.evaluation.explain import explain_result
    from reloc.evaluation.metrics import identifiable as identifiable_at
    from reloc.mapping import MappingParams, grow_submap, load_map
    from reloc.matching import MatchingParams, Relocalizer
    from reloc.progress import progress_bar
    from reloc.transforms import pose_error

    cfg = sequence_config(load_config(config_path), seq, quiet)
    mapping = MappingParams.from_config(cfg)
    k = window or mapping.submap_window_frames
    k_max = mapping.submap_max_window_frames if max_window is None else max_window
    if k_max and k_max < k:
        raise click.BadParameter(f"expected 0 or at least the window ({k} frames), got {k_max}",
                                 param_hint="--max-window")
    k_max = max(k, k_max)
    plane_map = load_map(map_path)
    sequence = open_sequence(seq)
    queries = parse_frames(frames_spec, len(sequence))[::every]
    plane_source = sequence_plane_source(seq, source, cfg)
    warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline"), quiet=quiet)
    reloc = Relocalizer(plane_map, MatchingParams.from_config(cfg))
    cache: dict[int, tuple] = {}
    extracted_ms = [0.0]  # extraction time spent while growing windows (not the submap's)

    def planes_of(i: int):
        if i not in cache:
            frame = sequence[i]
            t0 = time.perf_counter()
            cache[i] = (plane_source(frame), frame.T_world_cam, (time.perf_counter() - t0) * 1e3)
            extracted_ms[0] += cache[i][2]
            for old in [j for j in cache if j < i - stride * k_max]:
                del cache[old]
        return cache[i]

    def window_of(q: int, n: int) -> list:
        """The planes, poses and extraction times of the last ``n`` frames of the window ending at ``q``."""
        items = [planes_of(i) for i in range(q - stride * (n - 1), q + 1, stride) if i >= 0]
        if items[-1][1] is None:
            return items[-1:]  # no odometry for the query frame: a single-frame submap
        return [it for it in items if it[1] is not None]

    def truth_of(submap, res, T_true) -> dict:
        """The answer against the sequence's pose, and whether that pose is confirmed."""
        if T_true is None:
            return {"pose": None}
        out = {"translation_error_m": None, "rotation_error_deg": None}
        if res.relocalized:
            t_err, r_err = pose_error(res.T_map_cam, T_true)
            out.update(translation_error_m=round(t_err, 6), rotation_error_deg=round(r_err, 6))
        ident, why = identifiable_at(reloc, submap, T_true)
        out.update(identifiable=ident, reason=why)
        return out

    lines, counts = [], {"relocalized": 0, "rejected": 0, "error": 0}
    accounts: list[str] = []
    identifiable = 0
    for q in progress_bar(queries, desc="locate", unit="query", disable=quiet, leave=False):
        record = {"frame": int(q), "stamp_ns": int(sequence.stamps_ns[q])}
        try:
            newest = planes_of(q)
            t0 = time.perf_counter()
            extracted_ms[0] = 0.0
            fusion: dict = {}

            def fetch(n: int, q: int = q):
                items = window_of(q, n)
                return [it[0] for it in items], [it[1] for it in items]

            submap, used = grow_submap(fetch, k, k_max, mapping, fusion)  # one frame when q has no pose
            submap_ms = (time.perf_counter() - t0) * 1e3 - extracted_ms[0]
            trace = {} if explain_path else None
            res = reloc.locate(submap, trace=trace)
            d = res.to_dict()
            record.update(
                status=d["status"], reason=d["reason"], T_map_cam=d["T_map_cam"], covariance=d["covariance"],
                score=d["score"], ambiguity_ratio=d["ambiguity_ratio"], matched_planes=d["matched_planes"],
                window_frames=used, frames_left_out=fusion.get("frames_left_out", 0), counts=d["counts"],
                timings_ms={"extraction": round(float(newest[2]), 4), "submap": round(submap_ms, 4),
                            **d["timings_ms"]},
            )
            if check_poses:
                record["truth"] = truth_of(submap, res, newest[1])
                identifiable += int(bool(record["truth"].get("identifiable")))
            if explain_path:
                # With --check-poses the account reuses the identifiability checked above.
                truth = newest[1] if check_poses else None
                known = (record["truth"]["identifiable"], record["truth"]["reason"]) if truth is not None else None
                accounts.append(f"== frame {int(q)} (stamp_ns {record['stamp_ns']})\n"
                                + explain_result(reloc, submap, res, trace, truth, identified=known))
            counts[res.status] += 1
        except (ValueError, OSError) as exc:
            record.update(status="error", reason=str(exc), T_map_cam=None, covariance=None, score=None,
                          matched_planes=0)
            counts["error"] += 1
        lines.append(json.dumps(record))
    atomic_write_text(out_path, "\n".join(lines) + ("\n" if lines else ""))
    atomic_write_text(out_path + ".config.yaml", yaml.safe_dump(config_sections(cfg), sort_keys=False))
    if explain_path:
        atomic_write_text(explain_path, "\n\n".join(accounts) + ("\n" if accounts else ""))
    times = [json.loads(x).get("timings_ms", {}).get("total") for x in lines]
    times = [t for t in times if t is not None]
    med = f", median {np.median(times):.1f} ms per relocalization" if times else ""
    ident = f"; {identifiable} identifiable at the sequence's poses" if check_poses else ""
    click.echo(f"{out_path}: {len(lines)} queries: {counts['relocalized']} relocalized, {counts['rejected']} rejected, "
               f"{counts['error']} errors{med}{ident}")
    if lines and counts["error"] == len(lines):
        raise click.ClickException(f"every query failed (the first: {json.loads(lines[0])['reason']})")
