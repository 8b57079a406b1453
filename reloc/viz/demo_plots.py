"""The pictures of ``reloc demo --plots DIR``: one of each kind, from the demo's own map, queries and results.

- ``frame_planes.png``: a depth frame of the demo's scene (a random viewpoint, the same camera and noise) with the
  planes of the demo's plane source;
- ``map_submap.png``: the map from above with one relocalized positive query's submap at its estimated pose and the
  ground truth (a rejected one in orange at the truth when none was relocalized);
- ``reloc_results.png``: every positive query on the map, coloured by outcome, with its ground truth;
- ``eval_bars.png``: precision and recall by query kind, with the outcome counts;
- ``latency_hist.png``: per-stage latency histograms of the demo's relocalizations.
:func:`save_demo_rerun` writes the same as a Rerun recording (``reloc demo --rerun FILE.rrd``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["save_demo_plots", "save_demo_rerun"]


def _frame_with_planes(scene, spec, plane_source):
    """A frame from a few random viewpoints of ``scene``: the one with the most planes, and its planes."""
    import sim

    frames = sim.simulate_frames(scene, "random", 4, noise=spec["noise"], camera=spec["camera"],
                                 seed=spec["seed"], width=spec["width"], height=spec["height"])
    best = None
    for f in frames:
        planes = plane_source(f)
        if best is None or len(planes) > len(best[1]):
            best = (f, planes)
    return best


def save_demo_plots(result: dict, kept: dict, out_dir: str | Path) -> list[Path]:
    """Write the demo's pictures into ``out_dir`` (created); ``result`` is :func:`reloc.demo.run_demo`'s dict and
    ``kept`` what it put in ``keep``. Returns the paths written."""
    from reloc.viz.evaluation import eval_panels, plot_eval_bars
    from reloc.viz.frames import plot_frame_planes
    from reloc.viz.latency import latency_data, plot_latency
    from reloc.viz.maps import plot_map_topdown
    from reloc.viz.results import plot_reloc_results

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    spec, plane_map, reloc = result["spec"], kept["plane_map"], kept["relocalizer"]
    outcomes, queries = result["outcomes"], kept["queries"]
    written = []

    frame, planes = _frame_with_planes(kept["scene"], spec, kept["plane_source"])
    written.append(plot_frame_planes(
        frame, planes, out_dir / "frame_planes.png",
        title=f"{len(planes)} planes ({spec['plane_source']}) of a {spec['noise']}-noise frame, {spec['scene']}"))

    # Positive queries again (a few ms each) for their poses; the outcomes say which were right.
    records, truth, pick = [], {}, None
    for i, (q, o) in enumerate(zip(queries, outcomes)):
        if not o["positive"]:
            continue
        res = reloc.locate(q.submap)
        records.append({"frame": i, "status": res.status, "reason": res.reason,
                        "T_map_cam": None if res.T_map_cam is None else np.asarray(res.T_map_cam)})
        truth[i] = q.T_world_cam
        if pick is None or (o["label"] == "TP" and pick[2]["label"] != "TP"):
            pick = (q, res, o)
    if pick is not None:
        q, res, o = pick
        ok = res.status == "relocalized"
        written.append(plot_map_topdown(
            plane_map.planes, out_dir / "map_submap.png", submap=q.submap, T_map_cam=res.T_map_cam if ok else None,
            T_map_cam_gt=q.T_world_cam, relocalized=ok,
            title=f"query {q.name} ({len(q.submap)} planes) on the map ({o['label']})"))
        written.append(plot_reloc_results(
            plane_map.planes, records, out_dir / "reloc_results.png", truth=truth,
            title=f"demo: the {len(records)} positive queries on the map of {spec['scene']} (numbers: query index)"))

    written.append(plot_eval_bars(eval_panels(result), out_dir / "eval_bars.png",
                                  title=f"demo: relocalization in {spec['scene']}"))
    lat = latency_data(result)
    written.append(plot_latency(lat, out_dir / "latency_hist.png",
                                title=f"demo: latency per stage over {len(outcomes)} queries"))
    return written


def save_demo_rerun(result: dict, kept: dict, path: str | Path) -> Path:
    """Write a Rerun recording (``.rrd``) of the demo: the map, a frame with its planes, and each positive query's
    submap at its estimated pose beside the ground truth (timeline ``query``). Needs ``pip install rerun-sdk``."""
    from reloc.viz.rerun_log import log_frame, log_map, log_query, open_recording

    rec = open_recording(path)
    log_map(rec, kept["plane_map"].planes)
    frame, planes = _frame_with_planes(kept["scene"], result["spec"], kept["plane_source"])
    log_frame(rec, frame, planes)
    for i, (q, o) in enumerate(zip(kept["queries"], result["outcomes"])):
        if o["positive"]:
            res = kept["relocalizer"].locate(q.submap)
            log_query(rec, i, q.name, q.submap, res.status, res.T_map_cam, q.T_world_cam)
    rec.flush()
    return Path(path)
