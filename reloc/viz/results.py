"""Relocalization results on the map: every query's estimated camera, coloured by outcome, beside its ground truth.

Reads the records ``reloc locate`` writes (one JSON line per query: ``frame``, ``status``, ``reason``,
``T_map_cam``) with :func:`read_results`, and draws them over the map seen from above with
:func:`plot_reloc_results`. With ground truth (the query sequence's poses, in the map frame) a relocalized query is
"right" within the evaluation's TP tolerances (0.25 m, 5 deg) or "wrong pose"; rejected and failed queries are drawn
at their ground truth so that one sees where the misses are.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from reloc.planeset import PlaneSet
from reloc.transforms import check_transform, pose_error
from reloc.viz._mpl import REJECTED_COLOR, SUBMAP_COLOR, TRUTH_COLOR, new_figure, save_figure
from reloc.viz.maps import draw_map, finish_map_axes, topdown_basis

__all__ = ["read_results", "result_kinds", "plot_reloc_results", "STATUS_STYLE"]

WRONG_COLOR = "#c51b7d"  # relocalized at a wrong pose (magenta: not the truth's red)
ERROR_COLOR = "#737373"
UNCHECKED_COLOR = "#2166ac"  # relocalized, no ground truth to check it against

# outcome -> (colour, legend text)
STATUS_STYLE = {
    "right": (SUBMAP_COLOR, "relocalized, right pose"),
    "wrong": (WRONG_COLOR, "relocalized, wrong pose"),
    "relocalized": (UNCHECKED_COLOR, "relocalized (no ground truth)"),
    "rejected": (REJECTED_COLOR, "rejected (drawn at ground truth)"),
    "error": (ERROR_COLOR, "error (drawn at ground truth)"),
}


_LABEL_OFFSETS = ((5, 5), (5, -13), (-24, 5), (-24, -13))


def _free_offset(p: np.ndarray, labels: list, dots: list, per_point: float) -> tuple[int, int]:
    """The label offset (points) whose label centre is farthest from the labels placed so far and the other dots."""
    others = np.array(labels + [d for d in dots if np.hypot(*(d - p)) > 1e-9]).reshape(-1, 2)
    if not len(others):
        return _LABEL_OFFSETS[0]
    best = max(_LABEL_OFFSETS, key=lambda o: np.hypot(*(others - (p + per_point * (np.asarray(o) + (8, 3)))).T).min())
    return best


def read_results(path: str | os.PathLike) -> list[dict]:
    """The records of a ``reloc locate`` results file (JSON Lines). Raises ValueError naming the file, the line and
    the problem for anything else."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the results file ({exc})") from None
    records = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            r = json.loads(line)
        except ValueError as exc:
            raise ValueError(f"{path}:{lineno}: not JSON Lines of reloc locate ({exc})") from None
        if not isinstance(r, dict) or "status" not in r or "frame" not in r:
            raise ValueError(f"{path}:{lineno}: expected a reloc locate record with frame and status, got "
                             f"{line[:80]!r}")
        if r["status"] == "relocalized":
            try:
                r["T_map_cam"] = check_transform(np.asarray(r.get("T_map_cam"), dtype=float), "T_map_cam")
            except (ValueError, TypeError) as exc:
                raise ValueError(f"{path}:{lineno}: frame {r['frame']}: {exc}") from None
        records.append(r)
    if not records:
        raise ValueError(f"{path}: no records (an empty results file)")
    return records


def result_kinds(results: list[dict], truth: dict[int, np.ndarray] | None = None) -> list[tuple[str, tuple | None]]:
    """Per record: its kind (a key of :data:`STATUS_STYLE`) and, for a relocalized query with ground truth, its
    (translation error m, rotation error deg). Right means within the evaluation's TP tolerances."""
    from reloc.evaluation.metrics import TP_MAX_ROTATION_DEG, TP_MAX_TRANSLATION_M

    truth = truth or {}
    out = []
    for r in results:
        gt = truth.get(int(r["frame"]))
        if r["status"] == "relocalized":
            if gt is None:
                out.append(("relocalized", None))
                continue
            t_err, r_err = pose_error(r["T_map_cam"], gt)
            ok = t_err <= TP_MAX_TRANSLATION_M and r_err <= TP_MAX_ROTATION_DEG
            out.append(("right" if ok else "wrong", (t_err, r_err)))
        else:
            out.append(("rejected" if r["status"] == "rejected" else "error", None))
    return out


def _heading_tick(ax, T: np.ndarray, basis: np.ndarray, length: float, color: str, **kw) -> None:
    p = basis @ T[:3, 3]
    fwd = basis @ T[:3, 2]
    if np.linalg.norm(fwd) < 1e-6:
        fwd = basis @ T[:3, 0]
    q = p + length * fwd / np.linalg.norm(fwd)
    ax.plot([p[0], q[0]], [p[1], q[1]], color=color, **kw)


def plot_reloc_results(
    plane_map: PlaneSet,
    results: list[dict],
    path: str | os.PathLike,
    *,
    truth: dict[int, np.ndarray] | None = None,
    title: str | None = None,
    label_frames: int = 30,
    width_px: int = 1100,
    height_px: int = 900,
    max_points: int = 200_000,
):
    """Save a top-down PNG of ``plane_map`` (map frame) with every query of ``results`` (records of
    :func:`read_results`).

    - A relocalized query is a dot at its estimated camera position with a tick along the optical axis, coloured
      green (right pose) or magenta (wrong pose) when ``truth`` has its frame, blue otherwise.
    - ``truth``: frame index -> (4, 4) ``T_map_cam`` ground truth. Drawn as a red ring with a dashed tick, joined to
      the estimate by a thin line; rejected (orange) and failed (grey) queries are drawn there.
    - Frame numbers are written beside the queries when there are at most ``label_frames`` of them.
    Returns the path written.
    """
    truth = {int(k): check_transform(v, f"truth[{k}]") for k, v in (truth or {}).items()}
    basis = topdown_basis(plane_map.gravity)
    fig = new_figure(width_px, height_px)
    ax = fig.subplots()
    floor_xy, wall_xy = draw_map(ax, plane_map, basis, max_points)
    pts = np.concatenate([floor_xy, wall_xy]) if len(floor_xy) + len(wall_xy) else np.zeros((1, 2))
    tick = 0.035 * float(max(np.ptp(pts, axis=0).max(), 1.0))

    counts = {k: 0 for k in STATUS_STYLE}
    errors, placed = [], []
    dots = [basis @ (r["T_map_cam"] if k in ("right", "wrong", "relocalized") else truth[int(r["frame"])])[:3, 3]
            for r, (k, _) in zip(results, result_kinds(results, truth))
            if k in ("right", "wrong", "relocalized") or int(r["frame"]) in truth]
    per_point = float(max(np.ptp(pts, axis=0).max(), 1.0)) / (0.65 * min(width_px, height_px) * 0.72)  # m per pt
    label = len(results) <= label_frames
    for r, (kind, err) in zip(results, result_kinds(results, truth)):
        frame = int(r["frame"])
        gt = truth.get(frame)
        at = r["T_map_cam"] if kind in ("right", "wrong", "relocalized") else gt
        if kind == "right":
            errors.append(err)
        counts[kind] += 1
        color = STATUS_STYLE[kind][0]
        if gt is not None:
            g = basis @ gt[:3, 3]
            ax.plot(g[0], g[1], "o", ms=11, mfc="none", mec=TRUTH_COLOR, mew=1.6, zorder=5)
            _heading_tick(ax, gt, basis, tick, TRUTH_COLOR, lw=1.4, ls="--", zorder=5)
            if at is not None and kind in ("right", "wrong"):
                e = basis @ at[:3, 3]
                ax.plot([g[0], e[0]], [g[1], e[1]], color=color, lw=1.0, zorder=5)
        if at is None:
            continue  # rejected or failed without ground truth: counted in the legend only
        p = basis @ at[:3, 3]
        marker = "o" if kind in ("right", "wrong", "relocalized") else ("s" if kind == "rejected" else "X")
        ax.plot(p[0], p[1], marker, ms=7, color=color, mec="white", mew=0.8, zorder=6)
        _heading_tick(ax, at, basis, tick, color, lw=2.2, zorder=6)
        if label:
            # Queries close together: later labels go to another side of their dot instead of on top.
            offset = _free_offset(p, placed, dots, per_point)
            placed.append(p + per_point * (np.asarray(offset) + (8, 3)))
            ax.annotate(str(frame), (p[0], p[1]), xytext=offset,
                        textcoords="offset points", fontsize=8,
                        color="black", zorder=7,
                        bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.75))

    from matplotlib.lines import Line2D

    handles = [Line2D([], [], ls="none", marker="o", ms=6, color="#4d4d4d", label=f"map: {len(plane_map)} planes")]
    for kind, (color, text) in STATUS_STYLE.items():
        if counts[kind]:
            marker = "o" if kind in ("right", "wrong", "relocalized") else ("s" if kind == "rejected" else "X")
            handles.append(Line2D([], [], color=color, marker=marker, ms=7, lw=2.2, label=f"{text}: {counts[kind]}"))
    if truth:
        handles.append(Line2D([], [], color=TRUTH_COLOR, marker="o", mfc="none", ms=9, ls="--", lw=1.4,
                              label="ground truth"))
    handles.append(Line2D([], [], color="black", lw=0, label="ticks: camera's viewing direction"))
    fig.legend(handles=handles, loc="outside right upper", fontsize=9, frameon=False)
    finish_map_axes(ax, basis)
    n_rel = counts["right"] + counts["wrong"] + counts["relocalized"]
    head = title or "relocalization results"
    info = f"{len(results)} queries: {n_rel} relocalized, {counts['rejected']} rejected"
    if counts["error"]:
        info += f", {counts['error']} errors"
    if errors:
        e = np.asarray(errors)
        info += f"; right poses: median error {100 * np.median(e[:, 0]):.2f} cm, {np.median(e[:, 1]):.3f}°"
    ax.set_title(f"{head}\n{info}", fontsize=11)
    return save_figure(fig, path)
