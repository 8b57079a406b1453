"""``reloc profile``: per-stage latency of the pipeline in the shape of the paper's Table 8, with a Chrome trace.

Frames from any source go through plane extraction, the submap window and relocalization in a map; every stage is
timed with one :class:`reloc.profiling.Profiler`. The report has the paper's grouped rows (:data:`TABLE8_ROWS`) and
the detailed stages under them; the JSON (:func:`profile_report`) holds :meth:`Profiler.summary`, the grouped rows,
the raw samples of every stage (ms, for histograms), the numba compilation time (apart), the run, the machine and
the config.

Two modes:

- ``sequential`` (default): one thread runs each frame through extraction, the submap and relocalization, one after
  the other, every frame relocalized. Nothing else competes for the cores, so the stage times are those of the
  stages alone, and every stage has one sample per frame (the grouped rows are per-frame sums). In the trace the
  stages sit on the tracks of the live loop's threads (capture, processing, relocalization) on one timeline.
- ``live``: the threaded live loop (:class:`reloc.live.loop.LiveLoop`) with frames as fast as the source gives
  them: real threads and real tracks, but the relocalization thread competes with extraction for the cores (times
  include waiting for the GIL and the CPU) and relocalizes only when its triggers fire, not on every frame.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import click
import numpy as np

from reloc.profiling import Profiler, machine_info

__all__ = ["profile", "SequentialPipeline", "TABLE8_ROWS", "PAPER_TABLE8_MS", "table8", "profile_report",
           "format_report", "EXTRACT_STAGES", "RELOC_STAGES"]

# The stages the extraction and the relocalizer time (``reloc.extraction.pipeline.STAGES``,
# ``reloc.matching.relocalizer.STAGES`` and ``SUBSTAGES``; spelled out here so that this module imports without numba;
# a test keeps them equal).
EXTRACT_STAGES = ("backproject", "voxelize", "fit", "weight", "merge", "refine", "finalize")
RELOC_STAGES = ("prepare", "select", "transform", "verify", "decide", "decide.weights", "decide.density",
                "decide.tighten", "decide.probe", "decide.stronger", "refine")

# The paper's Table 8 rows and the profiler stages each one sums (stages are disjoint; their parts are not summed).
TABLE8_ROWS: dict[str, tuple[str, ...]] = {
    "single_frame": ("extract",),  # plane extraction of one frame, merging included
    "local_observation": ("submap",),  # the submap from the window of frames
    "localization": ("reloc.prepare", "reloc.select", "reloc.transform", "reloc.refine"),  # triplets, transforms
    "pose_likelihood": ("reloc.verify", "reloc.decide"),  # evaluation (Eq. 10-11), weights and kernel density
}
# The paper's Table 8 (ms; mean per relocalization on its machine).
PAPER_TABLE8_MS = {"single_frame": 53.763, "local_observation": 101.513, "localization": 157.471,
                   "pose_likelihood": 1165.624, "total": 1478.371}
_ROW_TITLES = {"single_frame": "Single frame", "local_observation": "Local observation",
               "localization": "Localization", "pose_likelihood": "Pose likelihood",
               "other": "Other (between stages)", "total": "Total"}
_DETAILS = {
    "single_frame": ["extract." + s for s in EXTRACT_STAGES],
    "local_observation": [],
    "localization": ["reloc.prepare", "reloc.select", "reloc.transform", "reloc.refine"],
    "pose_likelihood": ["reloc.verify", "reloc.decide", "reloc.decide.weights", "reloc.decide.density",
                        "reloc.decide.tighten", "reloc.decide.probe", "reloc.decide.stronger"],
}


@dataclass
class SequentialPipeline:
    """Extraction, submap window and relocalization of each frame on the calling thread, every stage timed.

    ``extract(frame)`` gives ``.planes`` and ``.timings_ms``; ``relocalizer.locate(submap)`` a result with
    ``.timings_ms``; ``fuse_submap(plane_sets, T_odom_cams)`` fuses the window (None stacks it). The window's odometry
    is each frame's own pose (``T_world_cam``, whatever its source); a frame without one restarts the window.

    Stages recorded per frame (only for frames that went through every stage, so all stages have the same count):
    ``extract`` and ``extract.<stage>``, ``submap``, ``reloc`` and ``reloc.<stage>``, and ``frame`` (the three
    together), on the tracks "processing" and "relocalization". A bad frame is counted in ``bad`` by reason. A frame
    during which numba compiled (or loaded from its cache) a kernel for new argument types is not recorded: its time
    goes to the profiler's compile time and it is counted in ``compiled_frames``.
    """

    extract: object
    relocalizer: object
    profiler: Profiler
    window_frames: int = 1
    fuse_submap: object = None
    processed: int = 0
    compiled_frames: int = 0
    statuses: dict = field(default_factory=dict)
    bad: dict = field(default_factory=dict)

    def __post_init__(self):
        from reloc.live.submap import SubmapWindow

        self._window = SubmapWindow(self.window_frames, fuse=self.fuse_submap)

    def reset(self) -> None:
        """Empty the submap window (after a warm-up pass)."""
        self._window.reset()

    def _bad(self, reason: str) -> None:
        self.bad[reason] = self.bad.get(reason, 0) + 1

    def process(self, frame):
        """One frame through every stage; returns the relocalization result, or None for a bad frame."""
        clock = time.perf_counter_ns
        signatures = _signature_count()
        if not np.any(frame.depth_m > 0):  # NaN compares False: all-NaN and all-zero frames have no measurement
            self._bad("no_valid_depth")
            return None
        t0 = clock()
        try:
            ext = self.extract(frame)
        except Exception as exc:  # noqa: BLE001 - a bad frame is counted, the run goes on
            self._bad(f"extraction_error:{type(exc).__name__}")
            return None
        t1 = clock()
        self._window.push(ext.planes, frame.T_world_cam, frame.seq)
        submap = self._window.build()
        t2 = clock()
        try:
            res = self.relocalizer.locate(submap)
        except Exception as exc:  # noqa: BLE001
            self._bad(f"relocalization_error:{type(exc).__name__}")
            return None
        t3 = clock()
        prof = self.profiler
        if _signature_count() != signatures:  # numba compiled during this frame: not a stage time
            prof.note_compile((t3 - t0) / 1e9)
            self.compiled_frames += 1
            return res
        prof.record("frame", t0, t3 - t0, "processing")
        prof.record("extract", t0, t1 - t0, "processing")
        prof.add_timings_ms({k: v for k, v in ext.timings_ms.items() if k != "total"}, "extract.", t1, "processing")
        prof.record("submap", t1, t2 - t1, "processing")
        prof.record("reloc", t2, t3 - t2, "relocalization")
        prof.add_timings_ms({k: v for k, v in res.timings_ms.items() if k != "total"}, "reloc.", t3, "relocalization")
        self.processed += 1
        self.statuses[res.status] = self.statuses.get(res.status, 0) + 1
        return res


def _signature_count() -> int:
    """Compiled specializations of every registered numba kernel (grows when a kernel compiles or loads)."""
    from reloc._numba import _KERNELS

    return sum(len(d.signatures) for d in _KERNELS)


def _row_stats(samples_ms: np.ndarray, total_ms: float, denom_ms: float) -> dict:
    n = int(samples_ms.size)
    p50, p95, p99 = np.percentile(samples_ms, [50, 95, 99]) if n else (math.nan,) * 3
    return {"count": n, "mean_ms": float(samples_ms.mean()) if n else math.nan, "p50_ms": float(p50),
            "p95_ms": float(p95), "p99_ms": float(p99), "max_ms": float(samples_ms.max()) if n else math.nan,
            "total_ms": float(total_ms), "share": float(total_ms / denom_ms) if denom_ms > 0 else math.nan}


def table8(profiler: Profiler, total_stage: str | None = "frame",
           denominator_stages: tuple[str, ...] = ("extract", "submap", "reloc")) -> tuple[dict, dict]:
    """The paper's grouped rows (:data:`TABLE8_ROWS`) from a profiler's stages: ``(rows, samples_ms)``.

    A row's samples are the element-wise sums of its stages' samples when those have the same count (one sample per
    frame or per query; else only its total and share are given). Shares are of ``total_stage``'s total (the whole
    pipeline per frame), or without it of the sum of ``denominator_stages``. ``other`` is the rest of that total
    (work between the stages: Python glue, result objects). Each row lists its ``stages`` and the ``paper_ms``.
    """
    stats = profiler.snapshot()
    if total_stage is not None and total_stage in stats:
        denom_ns = stats[total_stage][1]
    else:
        total_stage = None
        denom_ns = sum(stats[s][1] for s in denominator_stages if s in stats)
    rows, samples = {}, {}
    covered_ns = 0
    aligned: list[np.ndarray] = []
    for row, stages in TABLE8_ROWS.items():
        present = [s for s in stages if s in stats]
        total_ns = sum(stats[s][1] for s in present)
        covered_ns += total_ns
        counts = {stats[s][0] for s in present}
        sizes = {stats[s][2].size for s in present}
        if present and len(counts) == 1 and len(sizes) == 1:
            row_ns = np.sum([stats[s][2] for s in present], axis=0)
            aligned.append(row_ns)
        else:
            row_ns = np.zeros(0)
        rows[row] = {**_row_stats(row_ns / 1e6, total_ns / 1e6, denom_ns / 1e6), "stages": list(stages),
                     "paper_ms": PAPER_TABLE8_MS.get(row)}
        if not present:
            rows[row]["count"] = 0
        samples[row] = (row_ns / 1e6).tolist()
    other_ns = denom_ns - covered_ns
    if total_stage is not None:
        tot = stats[total_stage][2]
        ok = all(a.size == tot.size for a in aligned) and len(aligned) == len(TABLE8_ROWS)
        other = (tot - np.sum(aligned, axis=0)) if ok else np.zeros(0)
        rows["other"] = {**_row_stats(other / 1e6, other_ns / 1e6, denom_ns / 1e6), "stages": [],
                         "paper_ms": None}
        samples["other"] = (other / 1e6).tolist()
        rows["total"] = {**_row_stats(tot / 1e6, denom_ns / 1e6, denom_ns / 1e6), "stages": [total_stage],
                         "paper_ms": PAPER_TABLE8_MS["total"]}
        samples["total"] = (tot / 1e6).tolist()
    else:
        rows["other"] = {**_row_stats(np.zeros(0), other_ns / 1e6, denom_ns / 1e6), "stages": [], "paper_ms": None}
        rows["total"] = {**_row_stats(np.zeros(0), denom_ns / 1e6, denom_ns / 1e6),
                         "stages": list(denominator_stages), "paper_ms": PAPER_TABLE8_MS["total"]}
    return rows, samples


def profile_report(profiler: Profiler, *, total_stage: str | None = "frame", **info) -> dict:
    """The JSON of a profile: ``stages`` (:meth:`Profiler.summary`, shares of the whole pipeline), ``table8`` (the
    grouped rows), ``samples_ms`` (every stage's samples, ms), ``table8_samples_ms``, ``compile_s``, and ``info``."""
    rows, row_samples = table8(profiler, total_stage)
    summary = profiler.summary(total_stage if total_stage in profiler.stage_names else None)
    if total_stage not in profiler.stage_names:  # shares of the pipeline's stages together
        denom = rows["total"]["total_ms"]
        for s in summary["stages"].values():
            if math.isfinite(s["share"]):  # waits and end-to-end spans stay without a share (NaN)
                s["share"] = s["total_ms"] / denom if denom > 0 else math.nan
    samples = {k: (ns / 1e6).round(5).tolist() for k, (_, _, ns) in profiler.snapshot().items()}
    return {**info, "stages": summary["stages"], "table8": rows, "samples_ms": samples,
            "table8_samples_ms": {k: [round(x, 5) for x in v] for k, v in row_samples.items()},
            "compile_s": summary["compile_s"]}


def _fmt(x, spec=".3f") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def format_report(report: dict) -> str:
    """The grouped rows of Table 8 with the detailed stages under each, then the stages outside the total."""
    stages, rows = report["stages"], report["table8"]
    lines = []
    head = f"{'stage':<30} {'count':>6} {'p50 ms':>8} {'p95 ms':>8} {'p99 ms':>8} {'max ms':>8} {'share':>6} " \
           f"{'paper ms':>9}"
    lines += [head, "-" * len(head)]

    def line(name, r, paper=None):
        share = _fmt(100 * r["share"], "5.1f") + "%" if r["share"] == r["share"] else "-"
        paper = _fmt(paper, ".1f") if paper else ""
        lines.append(f"{name:<30} {r['count']:>6} {_fmt(r['p50_ms']):>8} {_fmt(r['p95_ms']):>8} "
                     f"{_fmt(r['p99_ms']):>8} {_fmt(r['max_ms']):>8} {share:>6} {paper:>9}")

    shown = set()
    details = {**_DETAILS, "total": ["extract", "submap", "reloc"]}
    for row in (*TABLE8_ROWS, "other", "total"):
        r = rows[row]
        line(_ROW_TITLES[row], r, r.get("paper_ms"))
        for s in details.get(row, []):
            if s in stages:
                line("  " * max(s.count("."), 1) + s, stages[s])
                shown.add(s)
        shown.update(r["stages"])
    rest = [s for s in stages if s not in shown]
    if rest:
        lines.append("not in the total:" if "frame" in stages else "other stages:")
        for s in rest:
            line("  " + s, stages[s])
    lines.append(f"numba compilation (warm-up, not in any stage): {report['compile_s']:.3f} s")
    return "\n".join(lines)


def _load_average() -> float | None:
    import os

    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return None


def _parse_size(size: str | None) -> dict:
    if size is None:
        return {}
    try:
        w, h = (int(x) for x in size.lower().split("x"))
        if w < 8 or h < 8:
            raise ValueError
    except ValueError:
        raise click.BadParameter(f"expected WIDTHxHEIGHT (at least 8x8), got {size!r}", param_hint="--size") from None
    return {"width": w, "height": h}


def _compile(extract, intrinsics) -> dict:
    """Compile (or load from the cache) every numba kernel before anything is timed; one flat frame extracted."""
    from reloc._numba import warm_up
    from reloc.camera import DepthFrame

    t0 = time.perf_counter()
    info = warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline"))
    try:
        extract(DepthFrame(np.full(intrinsics.shape, 2.0, np.float32), intrinsics, 0))
    except Exception:  # noqa: BLE001 - warm-up only; a real problem shows on the first real frame
        pass
    return {"kernels": info["kernels"], "cold_kernels": info["cold"], "seconds": time.perf_counter() - t0}


@click.command("profile")
@click.option("--camera", "camera", required=True, metavar="SOURCE",
              help="Frame source: sim[:SCENE], replay:DIR or a recorded folder, oak[:DEVICE_ID], rosbag:PATH.")
@click.option("--map", "map_spec", required=True, metavar="MAP",
              help="Plane map file from `reloc map build`, or sim:SCENE for the exact map of a simulated scene.")
@click.option("--frames", type=click.IntRange(min=1), default=200, show_default=True,
              help="Frames to time (after --warmup-frames).")
@click.option("--window", type=click.IntRange(min=1), default=None,
              help="Frames fused into each submap (default: mapping.submap_window_frames).")
@click.option("--mode", type=click.Choice(["sequential", "live"]), default="sequential", show_default=True,
              help="sequential: each frame through every stage on one thread, every frame relocalized (honest "
                   "per-stage times); live: the threaded live loop at full speed (real threads, contended cores, "
                   "relocalization only when triggered).")
@click.option("--warmup-frames", type=click.IntRange(min=0), default=1, show_default=True,
              help="Sequential mode: frames run through the pipeline untimed after the numba warm-up.")
@click.option("--size", default=None, metavar="WxH", help="Simulated camera only: image size, e.g. 320x200.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
              help="Write the profile (stages, Table 8 rows, raw samples in ms, compile time, run info) here.")
@click.option("--trace", "trace_path", type=click.Path(dir_okay=False), default=None,
              help="Write a Chrome trace event file (Perfetto, chrome://tracing), one track per thread.")
@click.option("--config", "config_path", type=click.Path(exists=True, dir_okay=False), default=None,
              help="YAML config (defaults otherwise).")
@click.option("--quiet", is_flag=True, help="Only the table.")
def profile(camera, map_spec, frames, window, mode, warmup_frames, size, json_path, trace_path, config_path, quiet):
    """Time every stage of the pipeline on frames from SOURCE and print p50/p95/p99/max and shares (Table 8).

    The grouped rows are the paper's: Single frame = plane extraction (merging included), Local observation = the
    submap of the last --window frames, Localization = ordering the submap planes, triplet selection, transforms
    and refinement, Pose likelihood = verification (Eq. 10-11) and the decision (frequency weights, kernel density,
    twin probe); the detailed stages are listed under each row. Numba compilation is done first and reported apart
    (a frame during which a kernel still compiled is left out of the stage times).

    Sequential mode (the default) runs the stages one after the other on one thread, every frame relocalized, so each
    stage's time is its own; its trace puts them on the tracks of the live loop's threads (capture, processing,
    relocalization) on one timeline. --mode live uses the threaded live loop (as `reloc run --rate fast`): real
    thread tracks, but the stages compete for the cores and relocalization runs only when triggered.
    """
    import json

    from drivers.source import SourceError
    from reloc.atomic import atomic_write_text, make_parent
    from reloc.config import config_as_dict, load_config
    from reloc.live.factory import (
        load_plane_map,
        make_extractor,
        make_relocalizer,
        make_submap_fuser,
        open_camera,
        with_camera_noise,
    )

    cfg = load_config(config_path)
    for option, target in (("--json", json_path), ("--trace", trace_path)):
        if target:  # before the run, not after it: a folder that cannot be made wastes the run and half its output
            try:
                make_parent(Path(target))
            except OSError as exc:
                raise click.BadParameter(exc.strerror or str(exc), param_hint=option) from None
    k = window or cfg.mapping.submap_window_frames
    echo = (lambda s: None) if quiet else (lambda s: click.echo(s, err=True))
    kwargs = _parse_size(size)
    if kwargs and camera.partition(":")[0] != "sim":
        raise click.UsageError("--size applies to a simulated camera (--camera sim[:SCENE]) only")
    n_warm = warmup_frames if mode == "sequential" else 0

    try:
        source = open_camera(camera, cfg, rate="fast", n_frames=frames + n_warm, **kwargs)
    except SourceError as exc:
        raise click.ClickException(str(exc)) from None
    try:
        cfg, note = with_camera_noise(cfg, source)
        if note:
            echo(note)
        t0 = time.perf_counter()
        map_planes, plane_map = load_plane_map(map_spec)
        relocalizer = make_relocalizer(plane_map, cfg)
        map_s = time.perf_counter() - t0
        echo(f"map: {len(map_planes)} planes from {map_spec} ({map_s:.2f} s with its index)")
        profiler = Profiler(window=max(8192, frames + 1), trace_capacity=(64 * frames + 1024) if trace_path else 0)
        run: dict = {"mode": mode, "window_frames": k}
        extract = make_extractor(cfg)
        compile_info = _compile(extract, source.intrinsics)
        profiler.note_compile(compile_info["seconds"])
        echo(f"numba: {compile_info['kernels']} kernels ready in {compile_info['seconds']:.2f} s "
             f"({compile_info['cold_kernels']} compiled on a cold cache)")
        t_run, cpu_run = time.perf_counter(), time.process_time()
        if mode == "sequential":
            run.update(_run_sequential(source, extract, relocalizer, profiler, k, make_submap_fuser(cfg), frames,
                                       n_warm, quiet))
        else:
            run.update(_run_live(source, extract, relocalizer, profiler, k, map_planes, cfg, frames, echo))
        run["wall_s"] = time.perf_counter() - t_run
        # CPU seconds of this process per wall second, and the load: on a shared machine stage times include
        # waiting for a core.
        run["cpu_s"] = time.process_time() - cpu_run
        run["load_average_1min"] = _load_average()
    finally:
        source.close()

    report = profile_report(
        profiler, total_stage="frame" if mode == "sequential" else None,
        command={"camera": camera, "map": map_spec, "frames": frames, "window": k, "mode": mode,
                 "warmup_frames": n_warm, "size": size, "config_file": config_path},
        run=run, map={"planes": len(map_planes), "load_and_index_s": map_s},
        compile=compile_info, machine=machine_info(), date=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        config=config_as_dict(cfg),
    )
    click.echo(format_report(report))
    click.echo(f"frames: {run['frames_processed']} timed, {run.get('frames_compiling', 0)} left out (numba compiled "
               f"during them), {sum(run['bad'].values())} bad {run['bad'] or ''}".rstrip()
               + f"; relocalizations: {run['statuses']}; {run['wall_s']:.1f} s wall, {run['cpu_s']:.1f} s CPU"
               + (f", load average {run['load_average_1min']:.1f}" if run["load_average_1min"] is not None else ""))
    if json_path:
        atomic_write_text(json_path, json.dumps(_plain(report), allow_nan=False) + "\n")
    if trace_path:
        profiler.write_chrome_trace(trace_path)


def _plain(x):
    """JSON-ready: numpy scalars as Python numbers, NaN and infinities as null."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _run_sequential(source, extract, relocalizer, profiler, window, fuse, frames, n_warm, quiet) -> dict:
    from reloc.progress import progress_bar

    pipe = SequentialPipeline(extract, relocalizer, profiler, window, fuse)
    it = iter(source)
    read = 0
    if n_warm:
        warm = SequentialPipeline(extract, relocalizer, Profiler(enabled=False), window, fuse)
        for _ in range(n_warm):
            frame = next(it, None)
            if frame is None:
                break
            warm.process(frame)
    profiler.reset()  # the trace starts here
    bar = progress_bar(total=frames, desc="profile", unit="frame", disable=quiet, leave=False)
    try:
        while read < frames:
            t0 = time.perf_counter_ns()
            frame = next(it, None)
            if frame is None:
                break
            profiler.record("capture.read", t0, time.perf_counter_ns() - t0, "capture")
            read += 1
            pipe.process(frame)
            bar.update(1)
    finally:
        bar.close()
    return {"frames_read": read, "frames_processed": pipe.processed, "frames_compiling": pipe.compiled_frames,
            "bad": dict(pipe.bad), "statuses": dict(pipe.statuses)}


def _run_live(source, extract, relocalizer, profiler, window, map_planes, cfg, frames, echo) -> dict:
    from dataclasses import replace

    from reloc.live.factory import make_submap_fuser
    from reloc.live.loop import LiveLoop
    from reloc.live.params import LiveParams

    params = LiveParams.from_config(cfg)
    # A window that grows grows from --window on (the config's limit may be below a --window given here).
    params = replace(params, window_frames=window,
                     max_window_frames=max(window, params.max_window_frames) if params.max_window_frames else 0)
    loop = LiveLoop(source, extract, relocalizer, params=params, map_planes=map_planes, odometry="source",
                    profiler=profiler, on_status=echo, fuse_submap=make_submap_fuser(cfg))
    summary = loop.run(max_frames=frames).to_dict()
    f = summary["frames"]
    statuses: dict = {}
    for r in loop.records():
        statuses[r.status] = statuses.get(r.status, 0) + 1
    return {"frames_read": f["captured"], "frames_processed": f["processed"], "frames_dropped": f["dropped"],
            "bad": dict(f["bad"]), "statuses": statuses, "relocalizations": summary["relocalizations_ok"]
            + summary["relocalizations_failed"]}
