"""Latency per stage: a histogram of each stage's durations with its p50 / p95 / p99 marked.

:func:`latency_data` reads stage timings from what the commands write: a profile (``reloc profile --json``:
``stages`` with percentiles and ``samples_ms`` with the durations), a live-loop summary (``reloc run --summary``:
percentiles only), the per-query ``timings_ms`` of ``reloc locate`` results (JSON Lines), ``reloc eval --json`` or
``reloc demo --json``. :func:`plot_latency` draws one histogram per stage; stages known only by their percentiles
are drawn as percentile bars on a log axis instead.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from reloc.viz._mpl import new_figure, save_figure

__all__ = ["LatencyData", "latency_data", "stats_from_samples", "plot_latency"]

_PCT_KEYS = ("p50_ms", "p95_ms", "p99_ms", "max_ms")
HIST_COLOR = "#6a51a3"


@dataclass
class LatencyData:
    """Per stage: ``stats`` (count, mean_ms, p50_ms, p95_ms, p99_ms, max_ms, total_ms, share) and, when known,
    ``samples_ms`` (1-D float arrays of durations in ms). ``compile_s``: numba compilation, outside every stage."""

    stats: dict[str, dict]
    samples_ms: dict[str, np.ndarray] = field(default_factory=dict)
    compile_s: float | None = None
    source: str = ""


def stats_from_samples(samples_ms: dict[str, list[float]], total_stage: str | None = "total") -> dict[str, dict]:
    """The profiler's per-stage summary (same keys as :meth:`reloc.profiling.Profiler.summary`) from raw durations.

    The share is relative to the summed time of the stages without a dot, ``total_stage`` (a sum itself, NaN share)
    left out: queries time stages outside their relocalization total (extraction, submap building) too."""
    clean = {k: np.asarray([v for v in vals if v is not None and math.isfinite(v)], dtype=float)
             for k, vals in samples_ms.items()}
    clean = {k: v for k, v in clean.items() if v.size}
    denom = float(sum(v.sum() for k, v in clean.items() if "." not in k and k != total_stage))
    out = {}
    for k, v in clean.items():
        p50, p95, p99 = np.percentile(v, [50, 95, 99])
        out[k] = {"count": int(v.size), "mean_ms": float(v.mean()), "p50_ms": float(p50), "p95_ms": float(p95),
                  "p99_ms": float(p99), "max_ms": float(v.max()), "total_ms": float(v.sum()),
                  "share": float(v.sum() / denom) if denom > 0 and k != total_stage else float("nan")}
    return out


def _from_records(records: list, what: str) -> LatencyData:
    samples: dict[str, list[float]] = {}
    for r in records:
        if not isinstance(r, dict):
            continue
        for k, v in (r.get("timings_ms") or {}).items():
            samples.setdefault(k, []).append(v)
        if "total" not in (r.get("timings_ms") or {}) and r.get("total_ms") is not None:
            samples.setdefault("total", []).append(r["total_ms"])
    if not samples:
        raise ValueError(f"{what}: expected per-query timings_ms, found none")
    stats = stats_from_samples(samples)
    return LatencyData(stats, {k: np.asarray([x for x in samples[k] if x is not None and math.isfinite(x)])
                               for k in stats}, None, what)


def _check_stats(stats, where: str) -> dict:
    if not isinstance(stats, dict) or not stats:
        raise ValueError(f"{where}: expected per-stage statistics, got {type(stats).__name__} {stats!r:.60}")
    for name, s in stats.items():
        if not isinstance(s, dict) or any(k not in s for k in ("p50_ms", "p95_ms", "max_ms")):
            raise ValueError(f"{where}[{name!r}]: expected p50_ms, p95_ms, p99_ms, max_ms, got "
                             f"{sorted(s) if isinstance(s, dict) else s!r:.80}")
    return stats


def latency_data(data, *, table8: bool = False) -> LatencyData:
    """Stage timings from the JSON of a profile, a live-loop summary, locate results, reloc eval or reloc demo.

    - profile (``reloc profile --json``): ``{"stages": {name: stats}, "samples_ms": {name: [ms...]},
      "compile_s": s}``; ``samples_ms`` may be missing (percentiles only).
    - live-loop summary (``reloc run --summary``): ``latency_ms`` and ``end_to_end_ms`` (percentiles only).
    - ``reloc locate`` results (a list of records), ``reloc demo --json`` or ``reloc eval --json`` (``outcomes``):
      the per-query ``timings_ms`` become samples.
    ``table8``: the profile's grouped rows in the shape of the paper's Table 8 (``table8``, ``table8_samples_ms``)
    instead of its stages. Raises ValueError saying what was expected otherwise.
    """
    if table8:
        if not isinstance(data, dict) or not isinstance(data.get("table8"), dict):
            raise ValueError("table8: expected a profile written by reloc profile --json (with table8), got "
                             + (f"keys {sorted(data)[:10]}" if isinstance(data, dict) else type(data).__name__))
        lat = latency_data({"stages": data["table8"], "samples_ms": data.get("table8_samples_ms"),
                            "compile_s": data.get("compile_s")})
        lat.source = "profile, the rows of Table 8"
        return lat
    if isinstance(data, list):
        return _from_records(data, "results")
    if not isinstance(data, dict):
        raise ValueError(f"expected a JSON object or JSON Lines of query records, got a JSON {type(data).__name__}")
    if "stages" in data:  # reloc profile --json (or Profiler.summary())
        stats = _check_stats(data["stages"], "stages")
        raw = data.get("samples_ms") or {}
        if not isinstance(raw, dict):
            raise ValueError(f"samples_ms: expected {{stage: [milliseconds]}}, got {type(raw).__name__}")
        try:
            samples = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in raw.items()}
        except (TypeError, ValueError) as exc:
            raise ValueError(f"samples_ms: expected lists of numbers ({exc})") from None
        compile_s = data.get("compile_s")
        return LatencyData(dict(stats), {k: v[np.isfinite(v)] for k, v in samples.items()},
                           None if compile_s is None else float(compile_s), "profile")
    if isinstance(data.get("latency_ms"), dict) and (
            not data["latency_ms"] or all(isinstance(v, dict) and "p50_ms" in v for v in data["latency_ms"].values())):
        stats = dict(data["latency_ms"])  # reloc run --summary
        for key, s in (data.get("end_to_end_ms") or {}).items():
            if isinstance(s, dict):
                stats[f"latency.{key}"] = s
        return LatencyData(_check_stats(stats, "latency_ms"), {}, None, "live-loop summary")
    outcomes = data.get("outcomes")
    if isinstance(outcomes, list):  # reloc demo --json
        lat = _from_records(outcomes, "outcomes")
        compile_s = (data.get("phases_s") or {}).get("compile_s")
        lat.compile_s, lat.source = compile_s, "demo"
        return lat
    if isinstance(outcomes, dict) and outcomes:  # reloc eval --json: the first method (Ours)
        name = "Ours" if "Ours" in outcomes else next(iter(outcomes))
        lat = _from_records(outcomes[name], f"outcomes[{name!r}]")
        lat.source = f"reloc eval, {name}"
        return lat
    raise ValueError("expected a profile (stages, samples_ms), a reloc run summary (latency_ms), reloc demo or "
                     f"reloc eval JSON (outcomes), or reloc locate results (JSON Lines); got keys {sorted(data)[:10]}")


def _order(lat: LatencyData, stages: list[str] | None, max_stages: int) -> list[str]:
    if stages:
        missing = [s for s in stages if s not in lat.stats]
        if missing:
            raise ValueError(f"stages: {missing} not in the file; it has {', '.join(lat.stats)}")
        return list(stages)
    # The stages that cost most first (total time, else mean x count).
    def cost(name):
        s = lat.stats[name]
        return s.get("total_ms") or s.get("mean_ms", s["p50_ms"]) * s.get("count", 1)

    return sorted(lat.stats, key=cost, reverse=True)[:max_stages]


def _fmt(ms: float | None) -> str:
    if ms is None or not math.isfinite(ms):
        return "-"
    return f"{ms:.3g}" if ms < 1 else f"{ms:.1f}" if ms < 100 else f"{ms:.0f}"


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def plot_latency(
    lat: LatencyData,
    path: str | os.PathLike,
    *,
    stages: list[str] | None = None,
    max_stages: int = 12,
    title: str | None = None,
    width_px: int = 1400,
    height_px: int | None = None,
    bins: int = 40,
):
    """Save a PNG of per-stage latency: one histogram per stage with samples (p50 solid, p95 dashed, p99 dotted,
    the x axis cut at 1.5 x p99 with the count of slower samples written in), and percentile bars (log axis) for
    stages known only by percentiles. ``stages``: which, in this order (default: the ``max_stages`` costliest).
    ``height_px`` None: about 250 px per row of three histograms. Returns the path written."""
    names = _order(lat, stages, max_stages)
    with_samples = [n for n in names if n in lat.samples_ms and lat.samples_ms[n].size]
    # Rows known by their total alone (a live profile's "other" and "total": overlapping threads) are left out.
    only_stats = [n for n in names if n not in with_samples and _finite(lat.stats.get(n, {}).get("p50_ms"))]
    if not with_samples and not only_stats:
        raise ValueError(f"no stage of {', '.join(names) or 'the file'} has samples or percentiles to plot")
    ncols = 1 if len(with_samples) == 1 else 2 if len(with_samples) in (2, 4) else 3
    nrows = math.ceil(len(with_samples) / ncols) if with_samples else 0
    stats_units = (0.5 + 0.2 * len(only_stats)) if only_stats else 0.0
    if height_px is None:
        height_px = int(max(260, 250 * nrows + 250 * stats_units + 80))
    fig = new_figure(width_px, height_px)
    head = title or (f"latency per stage ({lat.source})" if lat.source else "latency per stage")
    if lat.compile_s is not None:
        head += f"; numba compilation {lat.compile_s:.1f} s, not in any stage"
    fig.suptitle(head, fontsize=13, weight="bold")
    ratios = [1.0] * nrows + ([stats_units] if only_stats else [])
    grid = fig.add_gridspec(len(ratios), max(ncols, 1), height_ratios=ratios)

    for i, name in enumerate(with_samples):
        ax = fig.add_subplot(grid[i // ncols, i % ncols])
        v, s = lat.samples_ms[name], lat.stats[name]
        p50, p95, p99 = (float(x) for x in np.percentile(v, [50, 95, 99]))
        vmax = float(v.max())
        hi = vmax if vmax <= 1.5 * p99 or p99 <= 0 else 1.5 * p99
        beyond = int((v > hi).sum())
        # A long tail (p99 over 8 x p50) squeezes the bulk into one bin: log-spaced bins then, zeros counted apart.
        log = p50 > 0 and p99 > 8 * p50
        notes = [f"{beyond} beyond the axis"] if beyond else []
        if log:
            positive = v[v > 0]
            lo = max(float(positive.min()), hi / 1e4)
            edges = np.geomspace(lo, hi, bins + 1)
            ax.hist(np.clip(positive, lo, hi), bins=edges, color=HIST_COLOR, alpha=0.85, zorder=2)
            ax.set_xscale("log")
            from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

            # Plain numbers at 1, 2, 5 x 10^k (matplotlib's default writes 2x10^0 on every minor tick).
            ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0) if hi / lo < 300 else (1.0,)))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
            ax.xaxis.set_minor_formatter(NullFormatter())
            if (v <= 0).any():
                notes.append(f"{int((v <= 0).sum())} at 0 ms not shown")
        else:
            lo, hi = 0.0, max(hi, 1e-3)
            ax.hist(np.clip(v, lo, hi), bins=bins, range=(lo, hi), color=HIST_COLOR, alpha=0.85, zorder=2)
        for val, ls in ((p50, "-"), (p95, "--"), (p99, ":")):
            if val > (lo if log else -1):
                ax.axvline(val, color="black", ls=ls, lw=1.5, zorder=3)
        share = s.get("share")
        share_txt = f", share {100 * share:.0f}%" if share is not None and math.isfinite(share) else ""
        ax.set_title(f"{name}  (n={v.size}{share_txt})\n"
                     f"p50 {_fmt(p50)} | p95 {_fmt(p95)} | p99 {_fmt(p99)} | max {_fmt(vmax)} ms", fontsize=10,
                     loc="left")
        ax.set_xlim(lo, hi)
        ax.set_xlabel("ms, log axis" if log else "ms", fontsize=9)
        ax.tick_params(labelsize=8.5)
        ax.grid(True, axis="y", color="#e6e6e6", zorder=0)
        if notes:
            ax.text(0.98, 0.95, "; ".join(notes), transform=ax.transAxes, ha="right", va="top", fontsize=8,
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="#bbbbbb", alpha=0.9), zorder=4)
        if i % ncols == 0:
            ax.set_ylabel("samples", fontsize=9)

    if only_stats:
        ax = fig.add_subplot(grid[nrows, :])
        y = np.arange(len(only_stats))[::-1]
        vals = {k: np.array([max(float(lat.stats[n].get(k, np.nan) or np.nan), 1e-4) for n in only_stats])
                for k in _PCT_KEYS}
        ax.barh(y, vals["p50_ms"], color=HIST_COLOR, alpha=0.85, height=0.5, label="p50 (bar)", zorder=2)
        for key, marker, lab in (("p95_ms", "|", "p95"), ("p99_ms", "d", "p99"), ("max_ms", "x", "max")):
            ax.plot(vals[key], y, marker, color="black", ms=10, mew=2.2, ls="none", label=lab, zorder=3)
        finite = np.concatenate([v[np.isfinite(v)] for v in vals.values()])
        ax.set_xlim(finite.min() / 3, finite.max() * 2)
        for yi, n in zip(y, only_stats):
            s = lat.stats[n]
            ax.text(1.01, yi, f"p50 {_fmt(s['p50_ms'])} / p95 {_fmt(s['p95_ms'])} / p99 "
                    f"{_fmt(s.get('p99_ms', float('nan')))} / max {_fmt(s['max_ms'])} ms",
                    transform=ax.get_yaxis_transform(), va="center", fontsize=8.5)
        ax.set_yticks(y, only_stats, fontsize=9)
        ax.set_xscale("log")
        ax.set_xlabel("ms (log scale)", fontsize=9)
        ax.grid(True, axis="x", which="both", color="#e6e6e6", zorder=0)
        key = "bar p50, | p95, \u25c6 p99, \u00d7 max"
        ax.set_title(f"percentiles only, the file holds no samples ({key})" if not with_samples else
                     f"stages known by their percentiles only ({key})", fontsize=10.5, loc="left")
    if with_samples:
        from matplotlib.lines import Line2D

        fig.legend(handles=[Line2D([], [], color="black", ls=ls, lw=1.5, label=lab)
                            for ls, lab in (("-", "p50 (median)"), ("--", "p95"), (":", "p99"))],
                   loc="outside lower center", ncols=3, fontsize=9, frameon=False)
    return save_figure(fig, path)
