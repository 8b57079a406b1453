"""The plane set: what extraction produces for a frame and what maps, submaps and matching consume.

Stored as parallel arrays (one row per plane), never as a list of objects, so numba kernels and ``.npz`` files take
it as it is. All geometry is in the frame named by ``frame`` (``"cam"`` for a single frame, ``"map"`` for a map, the
latest camera for a submap).

Per plane ``i``:
- ``normals[i]`` (3,) unit, ``offsets[i]``: the plane ``n . p + d = 0``; the normal points to the side the sensor saw.
- ``centroids[i]`` (3,): mean of the supporting points.
- ``counts[i]``: number of supporting points.
- ``radii[i]``: largest distance of a supporting point from the centroid (the paper's sphere), metres.
- ``areas[i]``: area estimated by counting occupied l x l patches in the plane, m^2.
- ``covariances[i]`` (4, 4): covariance of ``(nx, ny, nz, d)`` from the fit.
- ``sums[i]`` (3,) and ``scatters[i]`` (3, 3): sufficient statistics (sum of points, sum of outer products
  ``p p^T`` about the origin) for fusing planes without revisiting points.
- Samples: a voxel-downsampled set of points of each plane, stored CSR-style: points
  ``sample_points[sample_ptr[i]:sample_ptr[i + 1]]`` belong to plane ``i``.

Frame-level:
- ``gravity`` (3,) unit vector of gravity (pointing down) in this frame, or None when unknown.
- ``gravity_tolerance_rad``: how far the true gravity may be from ``gravity``: 0 for a measured direction (IMU,
  a level base's mounting, a simulator), the camera's tilt tolerance when it is the camera's y axis (paper, tau_g).
  Matching widens its ground test by it.
- ``labels`` (H, W) int32 plane index per pixel (-1 for none), only for planes of one depth frame.
- ``viewpoints`` (V, 3): where the cameras that saw these planes were, in this frame (a submap: its window's
  cameras), or None when not recorded (a plane set in frame "cam" was seen from its origin). Matching uses them to
  tell a surface hidden behind a map surface from the cameras' positions under a pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["PlaneSet", "moved_geometry"]

_ROW_FIELDS = ("normals", "offsets", "centroids", "counts", "radii", "areas", "covariances", "sums", "scatters")
_ROW_SHAPES = {
    "normals": (3,), "offsets": (), "centroids": (3,), "counts": (), "radii": (), "areas": (),
    "covariances": (4, 4), "sums": (3,), "scatters": (3, 3),
}


def moved_geometry(T_a_b: np.ndarray, normals: np.ndarray, centroids: np.ndarray, covariances: np.ndarray,
                   sample_points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Planes' normals (N, 3), centroids (N, 3), (n, d) covariances (N, 4, 4) and float32 samples (M, 3) moved by
    ``T_a_b``: what :meth:`PlaneSet.transformed` does to them, for a caller that needs no more (and no new set)."""
    T = np.asarray(T_a_b, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    # (n, d) -> (R n, d - (R n) . t) is linear: J = [[R, 0], [-t^T R, 1]].
    J = np.zeros((4, 4))
    J[:3, :3] = R
    J[3, :3] = -t @ R
    J[3, 3] = 1.0
    return (normals @ R.T, centroids @ R.T + t, np.einsum("ij,njk,lk->nil", J, covariances, J),
            (sample_points.astype(np.float64) @ R.T + t).astype(np.float32))


@dataclass(frozen=True)
class PlaneSet:
    normals: np.ndarray
    offsets: np.ndarray
    centroids: np.ndarray
    counts: np.ndarray
    radii: np.ndarray
    areas: np.ndarray
    covariances: np.ndarray
    sums: np.ndarray
    scatters: np.ndarray
    sample_points: np.ndarray
    sample_ptr: np.ndarray
    frame: str = "cam"
    gravity: np.ndarray | None = None
    labels: np.ndarray | None = field(default=None, repr=False)
    gravity_tolerance_rad: float = 0.0
    viewpoints: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.asarray(self.normals).shape[0] if np.ndim(self.normals) == 2 else -1
        for name in _ROW_FIELDS:
            arr = getattr(self, name)
            dtype = np.int64 if name == "counts" else np.float64
            arr = np.ascontiguousarray(arr, dtype=dtype)
            expected = (n, *_ROW_SHAPES[name])
            if arr.shape != expected:
                raise ValueError(f"PlaneSet.{name}: expected shape {expected}, got {arr.shape}")
            object.__setattr__(self, name, arr)
        sp = np.ascontiguousarray(self.sample_points, dtype=np.float32).reshape(-1, 3)
        ptr = np.ascontiguousarray(self.sample_ptr, dtype=np.int64)
        if ptr.shape != (n + 1,) or ptr[0] != 0 or ptr[-1] != sp.shape[0] or np.any(np.diff(ptr) < 0):
            raise ValueError(
                f"PlaneSet.sample_ptr: expected a non-decreasing array of {n + 1} offsets from 0 to "
                f"{sp.shape[0]}, got shape {ptr.shape}"
            )
        object.__setattr__(self, "sample_points", sp)
        object.__setattr__(self, "sample_ptr", ptr)
        if self.gravity is not None:
            g = np.asarray(self.gravity, dtype=np.float64).reshape(3)
            with np.errstate(over="ignore", invalid="ignore"):
                norm = float(np.linalg.norm(g))
            if not (np.isfinite(norm) and norm > 1e-12):
                raise ValueError(f"PlaneSet.gravity: expected a finite non-zero 3-vector, got {g.tolist()}")
            object.__setattr__(self, "gravity", g / norm)
        tol = self.gravity_tolerance_rad
        if isinstance(tol, bool) or not isinstance(tol, (int, float, np.floating)) or not 0 <= tol <= np.pi / 2:
            raise ValueError(f"PlaneSet.gravity_tolerance_rad: expected a number in [0, pi/2], got {tol!r}")
        object.__setattr__(self, "gravity_tolerance_rad", float(tol))
        if self.viewpoints is not None:
            v = np.ascontiguousarray(self.viewpoints, dtype=np.float64)
            if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
                raise ValueError(f"PlaneSet.viewpoints: expected a finite (V, 3) array of camera positions, got "
                                 f"shape {v.shape}" + ("" if np.all(np.isfinite(v)) else " with non-finite values"))
            object.__setattr__(self, "viewpoints", v)

    def check_geometry(self, name: str) -> None:
        """Raise ``ValueError`` naming ``name`` unless every plane's geometry and statistics are finite, its normal
        unit and its area, radius and point count >= 0 (what matching and map files rely on)."""
        bad = [f for f in ("normals", "offsets", "centroids", "radii", "areas", "covariances", "sums", "scatters",
                           "sample_points") if not np.all(np.isfinite(getattr(self, f)))]
        if bad:
            raise ValueError(f"{name}: expected finite plane geometry, got non-finite {', '.join(bad)}")
        if len(self):
            with np.errstate(over="ignore"):  # a huge finite normal is reported below, not warned about
                err = float(np.abs(np.linalg.norm(self.normals, axis=1) - 1.0).max())
            if err > 1e-6:
                raise ValueError(f"{name}: expected unit normals, got |n| off by up to {err:.3g}")
            if self.areas.min() < 0 or self.radii.min() < 0 or self.counts.min() < 0:
                raise ValueError(f"{name}: expected areas, radii and counts >= 0, got minima {self.areas.min():.3g} "
                                 f"m^2, {self.radii.min():.3g} m and {self.counts.min()}")

    def __len__(self) -> int:
        return int(self.normals.shape[0])

    @property
    def planes(self) -> np.ndarray:
        """(N, 4) array of ``[nx, ny, nz, d]``."""
        return np.concatenate([self.normals, self.offsets[:, None]], axis=1)

    def samples_of(self, i: int) -> np.ndarray:
        """(M, 3) float32 sample points of plane ``i``."""
        return self.sample_points[self.sample_ptr[i] : self.sample_ptr[i + 1]]

    @classmethod
    def empty(cls, frame: str = "cam", gravity: np.ndarray | None = None, labels: np.ndarray | None = None,
              gravity_tolerance_rad: float = 0.0) -> "PlaneSet":
        return cls(
            normals=np.zeros((0, 3)), offsets=np.zeros(0), centroids=np.zeros((0, 3)), counts=np.zeros(0, np.int64),
            radii=np.zeros(0), areas=np.zeros(0), covariances=np.zeros((0, 4, 4)), sums=np.zeros((0, 3)),
            scatters=np.zeros((0, 3, 3)), sample_points=np.zeros((0, 3), np.float32), sample_ptr=np.zeros(1, np.int64),
            frame=frame, gravity=gravity, labels=labels, gravity_tolerance_rad=gravity_tolerance_rad,
        )

    def subset(self, index: np.ndarray) -> "PlaneSet":
        """The planes ``index`` (an integer array or a boolean mask), samples included; labels are dropped."""
        index = np.asarray(index)
        if index.size == 0 and index.dtype != np.bool_:
            index = index.astype(np.int64)  # [] reads as float: no planes
        idx = np.arange(len(self))[index]
        pieces = [self.samples_of(int(i)) for i in idx]
        sizes = np.array([len(p) for p in pieces], dtype=np.int64)
        ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        pts = np.concatenate(pieces) if pieces else np.zeros((0, 3), np.float32)
        return replace(
            self,
            **{name: getattr(self, name)[idx] for name in _ROW_FIELDS},
            sample_points=pts, sample_ptr=ptr, labels=None,
        )

    def transformed(self, T_a_b: np.ndarray, frame: str) -> "PlaneSet":
        """The same planes moved by ``T_a_b`` from this frame (b) into frame ``frame`` (a).

        Normals, offsets, centroids, samples, sufficient statistics, gravity, viewpoints and the (n, d) covariance
        all move; radii, areas and counts do not change. Labels are dropped (they belong to the original image).
        """
        T = np.asarray(T_a_b, dtype=np.float64)
        R, t = T[:3, :3], T[:3, 3]
        normals, centroids, covs, samples = moved_geometry(T, self.normals, self.centroids, self.covariances,
                                                           self.sample_points)
        offsets = self.offsets - normals @ t
        counts = self.counts.astype(np.float64)
        sums = self.sums @ R.T + counts[:, None] * t
        # sum (R p + t)(R p + t)^T = R S R^T + R s t^T + t s^T R^T + N t t^T
        Rs = self.sums @ R.T
        scatters = (
            np.einsum("ij,njk,lk->nil", R, self.scatters, R)
            + Rs[:, :, None] * t[None, None, :]
            + t[None, :, None] * Rs[:, None, :]
            + counts[:, None, None] * np.outer(t, t)[None]
        )
        gravity = None if self.gravity is None else R @ self.gravity
        views = None if self.viewpoints is None else self.viewpoints @ R.T + t
        return replace(
            self, normals=normals, offsets=offsets, centroids=centroids, sums=sums, scatters=scatters,
            covariances=covs, sample_points=samples, frame=frame, gravity=gravity, labels=None, viewpoints=views,
        )

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        """Plain arrays for ``np.savez`` (no objects, no pickle)."""
        out = {prefix + name: getattr(self, name) for name in _ROW_FIELDS}
        out[prefix + "sample_points"] = self.sample_points
        out[prefix + "sample_ptr"] = self.sample_ptr
        out[prefix + "gravity"] = np.full(3, np.nan) if self.gravity is None else self.gravity
        out[prefix + "gravity_tolerance_rad"] = np.float64(self.gravity_tolerance_rad)
        if self.viewpoints is not None:
            out[prefix + "viewpoints"] = self.viewpoints
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "", frame: str = "map") -> "PlaneSet":
        """Inverse of :meth:`to_arrays`; ``arrays`` is any mapping (an ``NpzFile`` included)."""
        kwargs = {name: np.asarray(arrays[prefix + name]) for name in _ROW_FIELDS}
        g = np.asarray(arrays[prefix + "gravity"], dtype=np.float64)
        # Absent from files written before it existed: their gravity was taken as measured.
        tol = float(np.asarray(arrays[prefix + "gravity_tolerance_rad"])) if (
            prefix + "gravity_tolerance_rad") in arrays else 0.0
        views = np.asarray(arrays[prefix + "viewpoints"]) if (prefix + "viewpoints") in arrays else None
        return cls(
            **kwargs, sample_points=np.asarray(arrays[prefix + "sample_points"]),
            sample_ptr=np.asarray(arrays[prefix + "sample_ptr"]), frame=frame,
            gravity=None if not np.all(np.isfinite(g)) else g, gravity_tolerance_rad=tol, viewpoints=views,
        )
