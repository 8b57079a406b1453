"""The evaluation as bars: precision and recall per scene, per plane source and per ablation, with the outcome counts.

:func:`eval_panels` reads what the evaluation writes - ``reloc eval --json`` (with or without ``--ablation``),
``benchmarks/reloc_accuracy.py``'s JSON, and ``reloc demo --json`` - into panels of summary rows;
:func:`plot_eval_bars` draws one panel per row of the picture: precision and recall in percent on the left, the
TP / FN / TN / FP counts behind them on the right (a reader sees at once what a 100% precision rests on).
"""

from __future__ import annotations

import math
import os

import numpy as np

from reloc.viz._mpl import new_figure, save_figure

__all__ = ["EvalPanel", "eval_panels", "plot_eval_bars", "rows_from_outcomes"]

PRECISION_COLOR = "#2c7fb8"
RECALL_COLOR = "#f28e2b"
COUNT_COLORS = {"TP": "#1a9850", "FN": "#fdae61", "TN": "#9ecae1", "FP": "#d62728"}
_COUNT_KEYS = ("TP", "TN", "FP", "FN")


class EvalPanel:
    """One panel: a title and rows (dicts with ``name``, ``TP``, ``TN``, ``FP``, ``FN``, ``precision``, ``recall``;
    precision and recall in [0, 1] or None when undefined)."""

    def __init__(self, title: str, rows: list[dict]):
        self.title = title
        self.rows = [_check_row(r, title) for r in rows]

    def __repr__(self) -> str:
        return f"EvalPanel({self.title!r}, {[r['name'] for r in self.rows]})"


def _check_row(row, where: str) -> dict:
    if not isinstance(row, dict) or "name" not in row or any(k not in row for k in _COUNT_KEYS):
        keys = sorted(row) if isinstance(row, dict) else type(row).__name__
        raise ValueError(f"{where}: expected rows with name, TP, TN, FP, FN (a summary of reloc eval), got {keys}")
    out = {"name": str(row["name"]), **{k: int(row[k]) for k in _COUNT_KEYS}}
    tp, fp, fn = out["TP"], out["FP"], out["FN"]
    for key, default in (("precision", tp / (tp + fp) if tp + fp else None),
                         ("recall", tp / (tp + fn) if tp + fn else None)):
        v = row.get(key, default)
        out[key] = None if v is None or (isinstance(v, float) and not math.isfinite(v)) else float(v)
    return out


def rows_from_outcomes(outcomes: list[dict], key) -> list[dict]:
    """Summary rows of query outcomes (dicts with ``label`` TP/TN/FP/FN) grouped by ``key(outcome)``, plus "all"."""
    groups: dict[str, list[str]] = {}
    for o in outcomes:
        groups.setdefault(str(key(o)), []).append(o["label"])
    groups["all"] = [o["label"] for o in outcomes]
    return [{"name": name, **{k: labels.count(k) for k in _COUNT_KEYS}} for name, labels in groups.items()]


def _spec_note(spec: dict | None) -> str:
    if not isinstance(spec, dict):
        return ""
    parts = [f"{spec['plane_source']} planes" if "plane_source" in spec else None,
             f"{spec['noise']} noise" if "noise" in spec else None,
             f"submaps of {spec['window_frames']} frames" if "window_frames" in spec else None]
    parts = [p for p in parts if p]
    return f" ({', '.join(parts)})" if parts else ""


def _demo_group(o: dict) -> str:
    parts = str(o.get("query", "")).split("/")
    if not o.get("positive", True):
        return f"negatives ({parts[0]})" if parts[0] else "negatives"
    return f"{parts[1]} queries" if len(parts) > 1 else "positives"


def eval_panels(data: dict, source: str | None = None) -> list[EvalPanel]:
    """Panels of the evaluation JSON ``data``, whichever command wrote it.

    - ``reloc eval --json``: per scene (and all); with ``--ablation`` also per method over all scenes.
    - ``benchmarks/reloc_accuracy.py``: per scene of ``source`` (a key of ``results.sources``; default the first
      "…/ours" source), every source's total side by side, and the ablation when it ran.
    - ``reloc demo --json``: the demo's queries by kind (robot-like, hand-held, negatives) and all.
    Raises ValueError saying what was expected when ``data`` is none of these.
    """
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object written by reloc eval, reloc demo or benchmarks/reloc_accuracy.py, "
                         f"got a JSON {type(data).__name__}")
    if isinstance(data.get("tables"), dict):  # reloc eval --json
        tables, note = data["tables"], _spec_note(data.get("spec"))
        panels = []
        if "by_method" in tables:
            panels.append(EvalPanel(f"per method, all scenes{note}", tables["by_method"]))
        per_scene = tables.get("Ours") or next((v for k, v in tables.items() if k != "by_method"), None)
        if per_scene:
            name = "Ours" if "Ours" in tables else next(k for k in tables if k != "by_method")
            panels.append(EvalPanel(f"per scene, {name}{note}", per_scene))
        if not panels:
            raise ValueError("tables: expected per-scene rows (reloc eval --json), got none")
        return panels
    results = data.get("results")
    if isinstance(results, dict) and isinstance(results.get("sources"), dict):  # benchmarks/reloc_accuracy.py
        sources = results["sources"]
        if not sources:
            raise ValueError("results.sources: expected at least one plane source, got none")
        if source is None:
            source = next((k for k in sources if k.endswith("/ours")), next(iter(sources)))
        if source not in sources:
            raise ValueError(f"source: expected one of {', '.join(sources)}, got {source!r}")
        try:
            chosen = sources[source]
            panels = [EvalPanel(f"per scene, {source}", chosen["per_scene"] + [chosen["total"]])]
            if len(sources) > 1:
                panels.append(EvalPanel("per plane source and matcher, all scenes",
                                        [{**v["total"], "name": k} for k, v in sources.items()]))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"results.sources[{source!r}]: expected per_scene and total, missing {exc}") from None
        if isinstance(results.get("ablation"), dict) and results["ablation"]:
            panels.append(EvalPanel("per ablation, all scenes (extraction planes, kinect noise)",
                                    [{**v, "name": k} for k, v in results["ablation"].items()]))
        return panels
    if isinstance(data.get("outcomes"), list) and "counts" in data:  # reloc demo --json
        spec = data.get("spec") or {}
        title = f"demo, scene {spec.get('scene', '?')}{_spec_note(spec)}"
        return [EvalPanel(title, rows_from_outcomes(data["outcomes"], _demo_group))]
    raise ValueError(f"expected the JSON of reloc eval --json (tables), benchmarks/reloc_accuracy.py (results.sources) "
                     f"or reloc demo --json (counts, outcomes), got keys {sorted(data)[:10]}")


def _panel_height(panel: EvalPanel) -> float:
    return 1.6 + len(panel.rows)


def plot_eval_bars(
    panels: list[EvalPanel],
    path: str | os.PathLike,
    *,
    title: str | None = None,
    width_px: int = 1300,
    height_px: int | None = None,
):
    """Save a PNG with one row per panel: precision and recall (%) as horizontal bars per row name on the left, the
    stacked TP / FN / TN / FP counts on the right. The "all" row is set apart by a line. ``height_px`` None: sized to
    the rows (about 40 px per bar group). Returns the path written."""
    if not panels:
        raise ValueError("panels: expected at least one panel, got none")
    units = [_panel_height(p) for p in panels]
    if height_px is None:
        height_px = int(max(300, 40 * sum(units) + (80 if title else 40)))
    fig = new_figure(width_px, height_px)
    if title:
        fig.suptitle(title, fontsize=13, weight="bold")
    axes = fig.subplots(len(panels), 2, gridspec_kw={"width_ratios": [2.2, 1.0], "height_ratios": units},
                        squeeze=False)
    for (ax_pr, ax_n), panel in zip(axes, panels):
        rows = panel.rows
        y = np.arange(len(rows))[::-1].astype(float)  # first row at the top
        h = 0.38
        for offset, key, color in ((h / 2, "precision", PRECISION_COLOR), (-h / 2, "recall", RECALL_COLOR)):
            vals = np.array([np.nan if r[key] is None else 100 * r[key] for r in rows])
            ax_pr.barh(y + offset, np.nan_to_num(vals), height=h, color=color, label=key, zorder=2)
            for yi, v in zip(y + offset, vals):
                text = "n/a" if not np.isfinite(v) else f"{v:.0f}%" if v in (0, 100) else f"{v:.1f}%"
                ax_pr.text((0 if not np.isfinite(v) else v) + 1, yi, text, va="center", fontsize=8.5, zorder=3)
        ax_pr.set_yticks(y, [r["name"] for r in rows], fontsize=9.5)
        ax_pr.set_xlim(0, 112)
        ax_pr.set_xticks([0, 25, 50, 75, 100])
        ax_pr.set_xlabel("%", fontsize=9)
        ax_pr.set_ylim(y.min() - 0.6, y.max() + 0.6)
        ax_pr.grid(True, axis="x", color="#e6e6e6", zorder=0)
        ax_pr.set_title(panel.title, fontsize=11, loc="left")

        # Outcomes as shares of each row's queries (rows of 40 and of 240 queries side by side), counts written in.
        n_row = np.array([sum(r[k] for k in _COUNT_KEYS) for r in rows], dtype=float)
        left = np.zeros(len(rows))
        for key in ("TP", "FN", "TN", "FP"):
            counts = np.array([r[key] for r in rows], dtype=float)
            share = np.divide(100 * counts, n_row, out=np.zeros_like(counts), where=n_row > 0)
            ax_n.barh(y, share, left=left, height=0.7, color=COUNT_COLORS[key], label=key, zorder=2)
            for yi, lo, v, c in zip(y, left, share, counts):
                if c and v >= 7:
                    ax_n.text(lo + v / 2, yi, f"{int(c)}", ha="center", va="center", fontsize=8, zorder=3,
                              color="white" if key in ("TP", "FP") else "black")
            left += share
        # A few FP or TP would be slivers: name them beside the row's query count.
        notes = []
        for r, n in zip(rows, n_row):
            small = [f"{r[k]} {k}" for k in ("FP", "TP", "FN") if r[k] and 100 * r[k] / max(n, 1) < 7]
            notes.append(f"n={int(n)}" + (f" ({', '.join(small)})" if small else ""))
        ax_n.set_yticks(y, notes, fontsize=8.5)
        ax_n.yaxis.tick_right()
        ax_n.set_ylim(y.min() - 0.6, y.max() + 0.6)
        ax_n.set_xlim(0, 100)
        ax_n.set_xticks([0, 25, 50, 75, 100])
        ax_n.set_xlabel("% of the row's queries", fontsize=9)
        ax_n.set_title("outcomes (counts written in)", fontsize=11, loc="left")
        if len(rows) > 1 and rows[-1]["name"] == "all":
            for ax in (ax_pr, ax_n):
                ax.axhline(y[-1] + 0.5, color="#555555", lw=0.8, ls="--", zorder=1)
    from matplotlib.patches import Patch

    handles = [Patch(color=PRECISION_COLOR, label="precision"), Patch(color=RECALL_COLOR, label="recall")] + [
        Patch(color=COUNT_COLORS[k], label=lab) for k, lab in (
            ("TP", "TP: right pose"), ("FN", "FN: missed"), ("TN", "TN: rightly rejected"), ("FP", "FP: wrong pose"))]
    fig.legend(handles=handles, loc="outside lower center", ncols=6, fontsize=9, frameon=False)
    return save_figure(fig, path)
