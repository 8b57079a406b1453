"""A prepared suite (maps and query submaps of every scene) on disk, so that matchers are compared without
rendering, extracting and fusing again.

Preparing the suite is the slow part of an evaluation (80-200 s a noise model on a 2-core machine, measured
2026-11-27, against seconds for relocalizing its 240 queries). :func:`save_prepared` writes a
:class:`~reloc.evaluation.suite.Prepared` into a directory: ``maps/<scene>.npz`` (map files,
:func:`reloc.mapping.save_map`), ``queries/<scene>.npz`` (each query's submap as plain arrays and its ground-truth
pose) and, last, ``suite.json`` (format and version, the :class:`~reloc.evaluation.suite.EvalSpec`, each query's name,
ambiguity label and timings, and whatever ``meta`` the caller adds, such as the parameters and the commit that built
it). Every file is written atomically and ``suite.json`` comes last, so an interrupted save leaves no directory that
loads. No pickle: ``.npz`` read with ``allow_pickle=False`` and JSON. :func:`load_prepared` raises
:class:`PreparedSuiteError` naming the file and the problem for anything it cannot read. :func:`built_with` records
every extraction and fusion parameter a suite is built from (callers store it in ``meta["params"]``) and
:func:`mismatch` names what differs between a loaded suite and the one asked for.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from reloc.atomic import atomic_write, atomic_write_text
from reloc.mapping import MapFileError, load_map, save_map

__all__ = ["PREPARED_FORMAT", "PREPARED_FORMAT_VERSION", "PreparedSuiteError", "built_with", "load_prepared",
           "load_queries", "mismatch", "save_prepared", "save_queries"]

PREPARED_FORMAT = "voxelplane-reloc prepared suite"
PREPARED_FORMAT_VERSION = 2  # 2: submaps carry their window's camera positions (viewpoints)


class PreparedSuiteError(ValueError):
    """A prepared-suite directory that cannot be read; the message names the file and the problem."""

    def __init__(self, path, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def save_prepared(directory, prepared, meta: dict | None = None) -> Path:
    """Write ``prepared`` (a :class:`~reloc.evaluation.suite.Prepared`) into ``directory``; returns the path of
    its ``suite.json``. ``meta`` (JSON-serialisable) is stored beside the spec; :func:`load_prepared` returns it.
    Saving over an earlier suite first removes its ``suite.json``, so an interrupted save never loads as either."""
    directory = Path(directory)
    (directory / "suite.json").unlink(missing_ok=True)
    index = {"format": PREPARED_FORMAT, "format_version": PREPARED_FORMAT_VERSION, "spec": asdict(prepared.spec),
             "meta": dict(meta or {}), "scenes": {}}
    for name in prepared.spec.scenes:
        save_map(directory / "maps" / f"{name}.npz", prepared.maps[name])
        arrays, listed = _query_arrays(prepared.queries[name])
        with atomic_write(directory / "queries" / f"{name}.npz", "wb") as fh:
            np.savez_compressed(fh, **arrays)
        index["scenes"][name] = {"map_seconds": float(prepared.map_seconds[name]), "queries": listed}
    path = directory / "suite.json"
    atomic_write_text(path, json.dumps(index, indent=1, sort_keys=True) + "\n")
    return path


def _query_arrays(queries) -> tuple[dict, list]:
    """The arrays of ``queries`` (submaps and ground-truth poses, keys ``q<i>_...``) and their JSON listing."""
    arrays, listed = {}, []
    for i, q in enumerate(queries):
        arrays.update(q.submap.to_arrays(f"q{i}_"))
        arrays[f"q{i}_T_world_cam"] = np.asarray(q.T_world_cam, dtype=np.float64)
        listed.append({"scene": q.scene, "name": q.name, "ambiguous": bool(q.ambiguous), "frame": q.submap.frame,
                       "timings_ms": {k: float(v) for k, v in q.timings_ms.items()},
                       "frames_left_out": int(q.frames_left_out), "window_frames": int(q.window_frames)})
    return arrays, listed


def _read_npz(path: Path) -> dict:
    with open(path, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":  # else numpy calls any non-zip file "pickled data"
            raise ValueError("not an .npz (zip) archive")
    with np.load(path, allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def _queries_from(arrays: dict, listed: list) -> list:
    """The queries that :func:`_query_arrays` turned into ``arrays`` and ``listed`` (ValueError, KeyError or
    TypeError when they do not fit together)."""
    from reloc.evaluation.suite import Query
    from reloc.planeset import PlaneSet

    qs = []
    for i, q in enumerate(listed):
        submap = PlaneSet.from_arrays(arrays, f"q{i}_", frame=str(q["frame"]))
        T = np.asarray(arrays[f"q{i}_T_world_cam"], dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"query {i}: T_world_cam of shape {T.shape}, expected (4, 4)")
        qs.append(Query(str(q["scene"]), str(q["name"]), T, submap, bool(q["ambiguous"]),
                        {str(k): float(v) for k, v in q["timings_ms"].items()}, int(q["frames_left_out"]),
                        int(q.get("window_frames", 0))))
    return qs


def save_queries(path, queries) -> Path:
    """Write ``queries`` (:class:`~reloc.evaluation.suite.Query`) into one ``.npz`` file, atomically: their arrays
    as in a prepared suite, and their listing as JSON text in ``listing``. For handing queries from one process to
    another without pickle (``reloc demo``'s helper)."""
    path = Path(path)
    arrays, listed = _query_arrays(queries)
    arrays["listing"] = np.array(json.dumps({"format": PREPARED_FORMAT, "format_version": PREPARED_FORMAT_VERSION,
                                             "queries": listed}))
    with atomic_write(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def load_queries(path) -> list:
    """The queries :func:`save_queries` wrote into ``path``; :class:`PreparedSuiteError` names the file and the
    problem when it cannot read them."""
    path = Path(path)
    try:
        arrays = _read_npz(path)
        index = json.loads(str(arrays.pop("listing")))
        if not isinstance(index, dict) or index.get("format") != PREPARED_FORMAT:
            raise ValueError(f"format {index.get('format') if isinstance(index, dict) else index!r}, expected "
                             f"{PREPARED_FORMAT!r}")
        if index.get("format_version") != PREPARED_FORMAT_VERSION:
            raise ValueError(f"format version {index.get('format_version')!r}, expected {PREPARED_FORMAT_VERSION}")
        return _queries_from(arrays, index["queries"])
    except FileNotFoundError:
        raise PreparedSuiteError(path, "missing") from None
    except (OSError, KeyError, TypeError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise PreparedSuiteError(path, f"unreadable queries ({exc!r})") from None


def _spec_from(data: dict, path: Path):
    from reloc.evaluation.suite import EvalSpec

    if not isinstance(data, dict):
        raise PreparedSuiteError(path, f"spec: expected an object, got {type(data).__name__}")
    known = {f.name for f in fields(EvalSpec)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise PreparedSuiteError(path, f"spec: unknown field(s) {', '.join(unknown)}")

    def tuples(v):
        return tuple(tuples(x) for x in v) if isinstance(v, list) else v

    try:
        return EvalSpec(**{k: tuples(v) for k, v in data.items()})
    except (TypeError, ValueError) as exc:
        raise PreparedSuiteError(path, f"spec: {exc}") from None


def load_prepared(directory):
    """Read a directory written by :func:`save_prepared`: returns ``(prepared, meta)``."""
    from reloc.evaluation.suite import Prepared

    directory = Path(directory)
    path = directory / "suite.json"
    if not directory.is_dir():
        raise PreparedSuiteError(directory, "no such directory, expected a prepared suite (save it with "
                                            "--save-prepared)")
    if not path.is_file():
        raise PreparedSuiteError(path, "missing: not a prepared suite, or its save did not finish")
    try:
        index = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PreparedSuiteError(path, f"unreadable ({exc})") from None
    if not isinstance(index, dict) or index.get("format") != PREPARED_FORMAT:
        got = index.get("format") if isinstance(index, dict) else type(index).__name__
        raise PreparedSuiteError(path, f"format {got!r}, expected {PREPARED_FORMAT!r}")
    if index.get("format_version") != PREPARED_FORMAT_VERSION:
        raise PreparedSuiteError(path, f"format version {index.get('format_version')!r}, this program reads "
                                       f"version {PREPARED_FORMAT_VERSION}; prepare the suite again")
    spec = _spec_from(index.get("spec"), path)
    scenes = index.get("scenes")
    if not isinstance(scenes, dict) or set(scenes) != set(spec.scenes):
        raise PreparedSuiteError(path, f"scenes {sorted(scenes) if isinstance(scenes, dict) else scenes!r} do not "
                                       f"match the spec's {sorted(spec.scenes)}")
    maps, seconds, queries = {}, {}, {}
    for name in spec.scenes:
        try:
            maps[name] = load_map(directory / "maps" / f"{name}.npz")
        except MapFileError as exc:
            raise PreparedSuiteError(exc.path, exc.problem) from None
        qpath = directory / "queries" / f"{name}.npz"
        entry = scenes[name]
        try:
            seconds[name] = float(entry["map_seconds"])
            qs = _queries_from(_read_npz(qpath), entry["queries"])
        except FileNotFoundError:
            raise PreparedSuiteError(qpath, "missing") from None
        except (OSError, KeyError, TypeError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise PreparedSuiteError(qpath, f"unreadable or inconsistent with suite.json ({exc!r})") from None
        queries[name] = qs
    return Prepared(spec, maps, seconds, queries), index.get("meta", {})


def built_with(spec, extraction=None, mapping=None) -> dict:
    """What the maps and queries of ``spec`` are built from, JSON-ready: every field of the extraction parameters
    as tuned to the spec's sensor (None for ground-truth planes) and of the map fusion parameters. Saved in a
    suite's ``meta["params"]`` and compared by :func:`mismatch` when it is loaded, so a default changed since the
    suite was saved is caught like an override (what the code does with them is not: a commit check is the
    caller's)."""
    from reloc.evaluation.suite import extraction_for_sensor
    from reloc.mapping import MappingParams

    ext = asdict(extraction_for_sensor(spec, extraction)) if spec.plane_source == "extraction" else None
    return json.loads(json.dumps({"extraction": ext, "mapping": asdict(mapping or MappingParams())}))


def _layer_share_resolved(ext):
    """Extraction parameters (a dict from :func:`built_with`) with ``layer_min_shared`` as the merge acts on it
    (``ExtractionParams.layer_share``): a suite saved when its default was 0.0 and one saved since it is null
    (4bb3ede) are the same suite for every sensor but stereo."""
    if ext.get("layer_min_shared", 0.0) is not None:
        return ext
    from reloc.extraction.params import STEREO_LAYER_MIN_SHARED

    return {**ext, "layer_min_shared": STEREO_LAYER_MIN_SHARED if ext.get("noise_model") == "stereo" else 0.0}


def mismatch(prepared, meta: dict, spec, params: dict) -> list[str]:
    """How a loaded suite (``prepared``, ``meta``) differs from the one asked for (``spec``, ``params`` from
    :func:`built_with`): one ``"name: saved X, asked Y"`` line per differing spec field or parameter; empty when
    it is the same suite."""
    out = [f"{f.name}: saved {getattr(prepared.spec, f.name)!r}, asked {getattr(spec, f.name)!r}"
           for f in fields(spec) if getattr(prepared.spec, f.name) != getattr(spec, f.name)]
    saved = meta.get("params")
    if not isinstance(saved, dict):
        return [*out, "no parameters recorded (saved by an older version): prepare it again"]
    for group in ("extraction", "mapping"):
        have, want = saved.get(group), params.get(group)
        if not isinstance(have, dict) or not isinstance(want, dict):
            if have != want:
                out.append(f"{group}: saved {have!r}, asked {want!r}")
            continue
        if group == "extraction":
            have, want = _layer_share_resolved(have), _layer_share_resolved(want)
        out += [f"{group}.{k}: saved {have.get(k, '(none)')!r}, asked {want.get(k, '(none)')!r}"
                for k in sorted(set(have) | set(want)) if have.get(k, "(none)") != want.get(k, "(none)")]
    return out
