"""The global plane map and its file.

A map file is an ``.npz`` archive (read with ``allow_pickle=False``) holding the map's plane set (arrays prefixed
``plane_``), the number of keyframes that saw each plane (``observations``), the known free space (``free_keys``,
sorted voxel keys, voxel edge ``free_voxel_m`` in the metadata; may be empty) and a JSON metadata entry (``meta``,
UTF-8 bytes): ``format`` ("voxelplane-reloc-map"), ``format_version``, ``config`` (the sections used to build it),
``source``, ``frame_count``, ``keyframe_count``, ``plane_count``, ``plane_source`` and ``created_utc``. Files are
written atomically. Reading a file of another version, a truncated or corrupted file, or a file that is not a map
raises :class:`MapFileError` naming the file and the problem.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import zipfile
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from reloc.atomic import atomic_write
from reloc.planeset import PlaneSet

__all__ = ["PlaneMap", "MapFileError", "save_map", "load_map", "MAP_FORMAT", "MAP_FORMAT_VERSION", "BENT_OFF_M",
           "BENT_FRACTION"]

MAP_FORMAT = "voxelplane-reloc-map"
MAP_FORMAT_VERSION = 1
# PlaneMap.consistency: a plane is bent when more than BENT_FRACTION of its samples lie more than BENT_OFF_M off it.
BENT_OFF_M = 0.06
BENT_FRACTION = 0.25
_PREFIX = "plane_"
# What reading a damaged archive raises (a flipped bit in an entry's compression method: NotImplementedError; in
# its flags: RuntimeError, "encrypted, password required"; an array header declaring terabytes: MemoryError).
_UNREADABLE = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError, RuntimeError,
               MemoryError)
_INT_ENTRIES = {_PREFIX + "counts", _PREFIX + "sample_ptr", "observations", "free_keys"}
_FLOAT_ENTRIES = {_PREFIX + name for name in ("normals", "offsets", "centroids", "radii", "areas", "covariances",
                                              "sums", "scatters", "sample_points", "gravity",
                                              "gravity_tolerance_rad")}


class MapFileError(ValueError):
    """A map file that cannot be used: ``path`` and ``problem`` say which and why."""

    def __init__(self, path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


@dataclass(frozen=True)
class PlaneMap:
    """Planes of a scene in the map frame (z up), each seen in ``observations[i]`` keyframes, with metadata.

    ``free_keys``: sorted int64 keys of the voxels (edge ``free_voxel_m``, keys as
    :func:`reloc.mapping.fusion.voxel_keys`) that depth rays crossed while mapping: known empty space (empty when
    the map was built without depth images).
    """

    planes: PlaneSet
    observations: np.ndarray
    meta: dict = field(default_factory=dict)
    free_keys: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    free_voxel_m: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.planes, PlaneSet):
            raise ValueError(f"PlaneMap.planes: expected a PlaneSet, got {type(self.planes).__name__}")
        obs = np.ascontiguousarray(self.observations, dtype=np.int64).reshape(-1)
        if obs.shape != (len(self.planes),):
            raise ValueError(f"PlaneMap.observations: expected shape ({len(self.planes)},), got {obs.shape}")
        object.__setattr__(self, "observations", obs)
        free = np.ascontiguousarray(self.free_keys, dtype=np.int64).reshape(-1)
        if len(free) and (not self.free_voxel_m > 0 or np.any(np.diff(free) <= 0) or free[0] < 0):
            raise ValueError(f"PlaneMap.free_keys: expected sorted unique voxel keys (>= 0) with free_voxel_m > 0, "
                             f"got {len(free)} keys from {free[0]}, free_voxel_m={self.free_voxel_m}")
        object.__setattr__(self, "free_keys", free)
        if self.planes.frame != "map":
            raise ValueError(f"PlaneMap.planes: expected frame 'map', got {self.planes.frame!r}")

    def __len__(self) -> int:
        return len(self.planes)

    @property
    def gravity(self) -> np.ndarray | None:
        return self.planes.gravity

    def summary(self) -> dict:
        """Counts and extents for ``reloc map info``."""
        from reloc.matching.index import horizontal_facing

        p = self.planes
        # Matching's ground test at its default tolerance (15 deg); a map without gravity is taken as z up.
        up_planes = p if p.gravity is not None else replace(p, gravity=np.array([0.0, 0.0, -1.0]))
        horizontal = horizontal_facing(up_planes, math.radians(15.0)) != 0
        lo = p.sample_points.min(axis=0).tolist() if len(p.sample_points) else None
        hi = p.sample_points.max(axis=0).tolist() if len(p.sample_points) else None
        return {
            "planes": len(p),
            "horizontal_planes": int(horizontal.sum()),
            "other_planes": int((~horizontal).sum()),
            "total_area_m2": round(float(p.areas.sum()), 3),
            "samples": int(len(p.sample_points)),
            "bounds_min_m": lo and [round(v, 3) for v in lo],
            "bounds_max_m": hi and [round(v, 3) for v in hi],
            "gravity": None if p.gravity is None else [round(float(v), 6) for v in p.gravity],
            "gravity_tolerance_deg": round(math.degrees(p.gravity_tolerance_rad), 3),
            "observations_median": float(np.median(self.observations)) if len(self.observations) else 0.0,
            "free_space_voxels": int(len(self.free_keys)),
            "free_space_m3": round(float(len(self.free_keys) * self.free_voxel_m**3), 3),
            **self.consistency(),
        }

    def consistency(self, off_m: float = BENT_OFF_M, bent_fraction: float = BENT_FRACTION) -> dict:
        """How well each plane fits its own samples, without ground truth: the fraction of all samples more than
        ``off_m`` from their plane, and the planes with more than ``bent_fraction`` of their samples that far (two
        surfaces fused into one plane: a wall and furniture in front of it, a wall and a door in its niche)."""
        p = self.planes
        counts = np.diff(p.sample_ptr)
        if len(p.sample_points) == 0:
            return {"samples_off_plane_fraction": 0.0, "bent_planes": 0, "bent_area_m2": 0.0}
        owner = np.repeat(np.arange(len(p)), counts)
        dist = np.abs(np.einsum("ij,ij->i", p.sample_points.astype(np.float64), p.normals[owner]) + p.offsets[owner])
        far = np.bincount(owner, weights=(dist > off_m).astype(np.float64), minlength=len(p))
        bent = far > bent_fraction * np.maximum(counts, 1)
        return {
            "samples_off_plane_fraction": round(float(far.sum() / len(dist)), 4),
            "bent_planes": int(bent.sum()),
            "bent_area_m2": round(float(p.areas[bent].sum()), 3),
        }


def save_map(path, plane_map: PlaneMap) -> Path:
    """Write ``plane_map`` to ``path`` (.npz) atomically; ``meta`` gains format, version, plane count and time."""
    if not isinstance(plane_map, PlaneMap):
        raise ValueError(f"plane_map: expected a PlaneMap, got {type(plane_map).__name__}")
    plane_map.planes.check_geometry("plane_map.planes")  # what load_map refuses is never written
    path = Path(path)
    meta = dict(plane_map.meta)
    meta.update(
        format=MAP_FORMAT,
        format_version=MAP_FORMAT_VERSION,
        plane_count=len(plane_map),
        free_voxel_m=float(plane_map.free_voxel_m),
        created_utc=meta.get("created_utc") or _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    )
    arrays = plane_map.planes.to_arrays(_PREFIX)
    arrays["observations"] = plane_map.observations
    arrays["free_keys"] = plane_map.free_keys
    arrays["meta"] = np.frombuffer(json.dumps(meta, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    with atomic_write(path, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return path


def load_map(path) -> PlaneMap:
    """Read a map written by :func:`save_map`; raises :class:`MapFileError` for anything else."""
    path = Path(path)
    if not path.exists():
        raise MapFileError(path, "no such file")
    if path.is_dir():
        raise MapFileError(path, "is a directory, expected a map file (.npz)")
    with open(path, "rb") as fh:
        head = fh.read(4)
    if not head:
        raise MapFileError(path, "empty file, expected a map file (.npz)")
    if head != b"PK\x03\x04":
        # Without this check numpy reports any non-zip file as "pickled data", which misleads.
        raise MapFileError(path, f"not a map file: not an .npz (zip) archive (starts with {head!r})")
    try:
        npz = np.load(path, allow_pickle=False)
    except _UNREADABLE as exc:
        raise MapFileError(path, f"truncated or corrupted .npz archive ({exc})") from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise MapFileError(path, "not a map file: a single .npy array, expected an .npz archive")
    with npz:
        if "meta" not in npz.files:
            raise MapFileError(path, f"not a map file: no 'meta' entry (entries: {', '.join(npz.files[:8])})")
        try:
            meta = json.loads(bytes(np.asarray(npz["meta"], dtype=np.uint8)).decode("utf-8"))
        except (*_UNREADABLE, TypeError, RecursionError) as exc:
            raise MapFileError(path, f"truncated or corrupted: cannot read the metadata ({exc})") from None
        if not isinstance(meta, dict) or meta.get("format") != MAP_FORMAT:
            got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
            raise MapFileError(path, f"not a map file: format {got!r}, expected {MAP_FORMAT!r}")
        version = meta.get("format_version")
        if version != MAP_FORMAT_VERSION:
            raise MapFileError(
                path, f"map format version {version!r}, this program reads version {MAP_FORMAT_VERSION}; rebuild "
                "the map with `reloc map build`"
            )
        try:
            arrays = {name: npz[name] for name in npz.files if name != "meta"}
        except _UNREADABLE as exc:
            raise MapFileError(path, f"truncated or corrupted: cannot read its arrays ({exc})") from None
    # Numbers only, of the kind each array holds: no text parsed as numbers, no records, no complex values.
    for name, arr in arrays.items():
        if not isinstance(arr, np.ndarray):  # an entry that is not .npy data comes back as its bytes
            raise MapFileError(path, f"corrupted: entry {name!r} is not an array ({type(arr).__name__})")
        want = "iu" if name in _INT_ENTRIES else "f" if name in _FLOAT_ENTRIES else None
        if want is not None and arr.dtype.kind not in want:
            raise MapFileError(path, f"corrupted: array {name!r} has dtype {arr.dtype}, expected "
                                     f"{'integers' if want == 'iu' else 'floating point numbers'}")
    free_voxel_m = meta.get("free_voxel_m", 0.0)
    if isinstance(free_voxel_m, bool) or not isinstance(free_voxel_m, (int, float)) or not (
            math.isfinite(free_voxel_m) and free_voxel_m >= 0):
        raise MapFileError(path, f"corrupted: metadata free_voxel_m {free_voxel_m!r}, expected a finite number >= 0")
    raw_g = arrays.get(_PREFIX + "gravity")
    if raw_g is not None:
        # Stored as NaN when there is none; a PlaneSet takes any other non-finite vector for none too, and scales a
        # long one to unit length, so a damaged vector is refused here.
        g = raw_g.astype(np.float64).reshape(-1)
        with np.errstate(over="ignore"):  # a huge finite vector is refused below, not warned about
            unit = g.shape == (3,) and bool(np.all(np.isfinite(g))) and abs(float(np.linalg.norm(g)) - 1.0) < 1e-6
        if not (unit or (g.shape == (3,) and np.all(np.isnan(g)))):
            raise MapFileError(path, f"corrupted: gravity {g.tolist()} is not a direction (expected a unit 3-vector, "
                                     "or NaN for none)")
    try:
        planes = PlaneSet.from_arrays(arrays, _PREFIX, frame="map")
        observations = arrays["observations"]
        free = arrays["free_keys"]
        if free.dtype != np.int64:
            raise ValueError(f"free_keys: expected int64, got {free.dtype}")
        plane_map = PlaneMap(planes, observations, meta, free_keys=free, free_voxel_m=float(free_voxel_m))
    except KeyError as exc:
        raise MapFileError(path, f"corrupted: missing array {exc}") from None
    except (ValueError, TypeError) as exc:
        raise MapFileError(path, f"corrupted: inconsistent arrays ({exc})") from None
    if meta.get("plane_count") != len(plane_map):
        raise MapFileError(path, f"corrupted: metadata says {meta.get('plane_count')} planes, arrays hold "
                                 f"{len(plane_map)}")
    try:
        planes.check_geometry("planes")
    except ValueError as exc:
        raise MapFileError(path, f"corrupted: {exc}") from None
    return plane_map
