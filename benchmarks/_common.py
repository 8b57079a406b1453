"""Helpers shared by the benchmark scripts: tables on stdout, results as JSON with their provenance.

Every benchmark writes ``benchmarks/results/<name>.json`` holding the date, the machine (CPU model, cores), the git
commit (and whether the tree had local changes), the resolved parameters of the run and its results, so a figure
can always be traced back to the code and settings that produced it.

Benchmarks are scripts, not an installed package: run them from the repository root as
``python benchmarks/<name>.py``; this module is imported as ``_common`` from the script's own folder, before
anything of the project. Importing it puts this checkout's root first on ``sys.path``, so the code measured is the
code whose commit the results name, also when the script is run from a second checkout (a ``git worktree`` of an
older commit, for a before/after comparison) with the virtual environment of the first, whose editable install
would otherwise supply ``reloc`` and ``sim`` from the first checkout. The results record where ``reloc`` came from
(``git.code_root``) and whether that is this checkout (``git.code_is_checkout``).
"""

from __future__ import annotations

import ast
import dataclasses
import datetime as _dt
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

__all__ = [
    "REPO_ROOT",
    "RESULTS_DIR",
    "code_root",
    "machine_info",
    "git_info",
    "jsonable",
    "format_table",
    "print_table",
    "write_results",
    "parse_overrides",
    "results_name",
]

REPO_ROOT = Path(__file__).resolve().parents[1]
# Where results go: benchmarks/results, or RELOC_RESULTS_DIR (a test's smoke run writes there, not into the checkout).
RESULTS_DIR = Path(os.environ.get("RELOC_RESULTS_DIR") or REPO_ROOT / "benchmarks" / "results")
if str(REPO_ROOT) not in sys.path[:1]:
    sys.path.insert(0, str(REPO_ROOT))


def machine_info() -> dict:
    """CPU (model name, family / model numbers, LLVM's name for its microarchitecture), cores, OS and versions:
    :func:`reloc.profiling.machine_info`."""
    from reloc.profiling import machine_info as info

    return info()


def code_root() -> Path | None:
    """The folder the ``reloc`` package was imported from (its parent), or None when it is not imported."""
    mod = sys.modules.get("reloc")
    path = getattr(mod, "__file__", None)
    return Path(path).resolve().parents[1] if path else None


def git_info(root: Path = REPO_ROOT) -> dict:
    """``{"commit": sha or None, "dirty": bool or None, "code_root": path or None, "code_is_checkout": bool or
    None}`` of the repository at ``root``: the last two say where ``reloc`` was imported from and whether that is
    ``root`` (when it is not, the commit does not describe the code that ran)."""

    def run(*args: str) -> str | None:
        try:
            out = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return out.stdout.strip() if out.returncode == 0 else None

    commit = run("rev-parse", "HEAD")
    status = run("status", "--porcelain", "--untracked-files=no")
    code = code_root()
    return {"commit": commit, "dirty": None if status is None else bool(status),
            "code_root": None if code is None else str(code),
            "code_is_checkout": None if code is None else code == Path(root).resolve()}


def jsonable(obj: Any) -> Any:
    """Turn numpy scalars/arrays, dataclasses, paths and non-finite floats into plain JSON values.

    NaN and infinities become ``None`` (JSON has no spelling for them).
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return jsonable(dataclasses.asdict(obj))
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    return str(obj)


def _cell(value: Any, floatfmt: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, (float, np.floating)):
        return "nan" if not math.isfinite(float(value)) else format(float(value), floatfmt)
    return str(value)


def format_table(
    headers: Sequence[str],
    rows: Iterable[Sequence[Any]],
    *,
    title: str | None = None,
    floatfmt: str | Sequence[str] = ".4f",
) -> str:
    """A plain-text table: first column left-aligned, the others right-aligned.

    ``floatfmt`` is one format for every float or one per column; ``None`` cells print as ``-``.
    """
    rows = [list(r) for r in rows]
    n = len(headers)
    fmts = [floatfmt] * n if isinstance(floatfmt, str) else list(floatfmt)
    if len(fmts) != n:
        raise ValueError(f"floatfmt: expected one format or {n}, got {len(fmts)}")
    cells = [[_cell(v, fmts[j]) for j, v in enumerate(r)] for r in rows]
    for i, r in enumerate(cells):
        if len(r) != n:
            raise ValueError(f"rows[{i}]: expected {n} cells, got {len(r)}")
    widths = [max([len(h)] + [len(r[j]) for r in cells]) for j, h in enumerate(headers)]

    def line(parts: Sequence[str]) -> str:
        return "  ".join(p.ljust(widths[j]) if j == 0 else p.rjust(widths[j]) for j, p in enumerate(parts))

    out = []
    if title:
        out.append(title)
    out.append(line(headers))
    out.append("  ".join("-" * w for w in widths))
    out.extend(line(r) for r in cells)
    return "\n".join(out)


def print_table(headers: Sequence[str], rows: Iterable[Sequence[Any]], **kwargs) -> str:
    """Print :func:`format_table` (and a blank line) to stdout; return the text."""
    text = format_table(headers, rows, **kwargs)
    print(text + "\n", flush=True)
    return text


def write_results(name: str, *, params: dict, results: Any, out_dir: Path | None = None) -> Path:
    """Write ``<out_dir>/<name>.json`` atomically with date, machine, git state, ``params`` and ``results``.

    ``out_dir`` defaults to ``benchmarks/results`` (``RELOC_RESULTS_DIR`` when set). Returns the path written.
    """
    from reloc.atomic import atomic_write_text

    path = (out_dir or RESULTS_DIR) / f"{results_name(name)}.json"
    git = git_info()
    if git["code_is_checkout"] is False:
        print(f"warning: reloc was imported from {git['code_root']}, not from {REPO_ROOT} whose commit the results "
              "name", file=sys.stderr)
    payload = {
        "benchmark": name,
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else "",
        "machine": machine_info(),
        "git": git,
        "params": params,
        "results": results,
    }
    atomic_write_text(path, json.dumps(jsonable(payload), indent=1, allow_nan=False) + "\n")
    return path


def quick_presets(ap, args, presets: dict, argv: Sequence[str] | None = None) -> list[str]:
    """A smoke run's settings: each of ``presets`` (argparse dest -> value) is set on ``args`` unless its option was
    given on the command line (``argv``, default ``sys.argv[1:]``), which wins. Returns the dests kept as given."""
    unset = object()
    saved = {dest: ap.get_default(dest) for dest in presets}
    ap.set_defaults(**{dest: unset for dest in presets})
    try:
        probe = ap.parse_args(argv)
    finally:
        ap.set_defaults(**saved)
    kept = [dest for dest in presets if getattr(probe, dest) is not unset]
    for dest, value in presets.items():
        if dest not in kept:
            setattr(args, dest, value)
    return kept


def parse_overrides(items: Iterable[str], option: str = "--set") -> dict:
    """``KEY=VALUE`` strings (a repeatable ``--set`` option) to a dict: VALUE (spaces around it dropped) parsed as a
    Python literal (numbers, True, None, tuples), ``true`` / ``false`` in any case as the config files spell them, else
    kept as a string. Raises ValueError naming an item without ``=`` or without a key."""
    out: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        value = value.strip()
        if not sep or not key.strip():
            raise ValueError(f"{option}: expected KEY=VALUE, got {item!r}")
        if value.lower() in ("true", "false"):
            out[key.strip()] = value.lower() == "true"
            continue
        try:
            out[key.strip()] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[key.strip()] = value
    return out


def results_name(name: str, flag: str = "--name") -> str:
    """``name`` if it is a plain file stem for ``benchmarks/results`` (checked when a script starts, not after an
    hour of measuring), else ValueError naming the option ``flag`` it came from."""
    if not name or any(c in name for c in "/\\") or name in (".", ".."):
        raise ValueError(f"{flag}: expected a plain file stem for benchmarks/results/, got {name!r}")
    return name
