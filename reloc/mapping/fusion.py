"""Fusing planes seen from several poses into one plane per physical surface.

Planes (already in one common frame) are associated with the planes accumulated so far when their normals agree
within ``max_angle_rad``, the new plane's samples lie within ``max_offset_m`` of the old plane (median) with at most
``max_far_fraction`` of them beyond twice that, and the two touch:
at least ``min_overlap`` of the new plane's sample voxels have a voxel of the old plane among their 26 neighbours
(0 means one is enough). With ``check_local`` the old plane's own samples around the new plane must also lie
within ``max_offset_m`` of the new plane (median): the test against the old plane alone let a door 6 cm deep in its
niche join the wall around it, once that wall's fused plane had turned a little, and each join turned it further.
Off by default: it leaves fewer bent planes in the suite's maps, but relocalization on them answered more views and
let in more false positives (docs/BENCHMARKS.md, "A map plane judged by its own samples where a plane joins it").
Associated planes are fused by their information: each input plane's (n, d) with its
covariance (the robust, noise-weighted fit of extraction) contributes ``I_k = C_k^+``; the fused plane minimizes
``sum (x - x_k)^T I_k (x - x_k)`` on the unit-normal manifold. The sufficient statistics (count, sum of points,
sum of outer products) are fused too: they give the centroid, and the plane itself for inputs without a usable
covariance (the least-squares plane of all supporting points, without revisiting them). Samples are fused per
voxel (sum and count per voxel of edge ``spacing_m``). A new plane associated with several accumulated planes
merges them (a wall seen in pieces becomes one plane). With ``check_bridged`` the new plane goes to the one it fits
best (median offset of its samples), and the others join that one only where they agree with it themselves: normals
within ``max_angle_rad`` and each one's samples within ``max_offset_m`` of the other's plane (median). Without that
check one far, mixed plane (a stereo wall fused with furniture in front of it) made a TV's 0.7 m^2 face and tilted
planes of 2-5 m^2 one map plane of 8.1 m^2 in the simulated living room.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reloc.planeset import PlaneSet
from reloc.rowkeys import count_unique_rows

__all__ = [
    "FusionParams",
    "PlaneAccumulator",
    "plane_fit_from_stats",
    "voxel_keys",
    "fraction_touching",
    "patch_area",
]

_OFF = 1 << 20
_MASK = (1 << 21) - 1


@dataclass(frozen=True)
class FusionParams:
    max_angle_rad: float = math.radians(8.0)
    max_offset_m: float = 0.06
    min_overlap: float = 0.0
    spacing_m: float = 0.1
    check_bridged: bool = True
    max_far_fraction: float = 0.25
    check_local: bool = False

    def __post_init__(self) -> None:
        if not (0 < self.max_angle_rad < math.pi / 2):
            raise ValueError(f"max_angle_rad: expected in (0, pi/2), got {self.max_angle_rad}")
        if not self.max_offset_m > 0:
            raise ValueError(f"max_offset_m: expected > 0, got {self.max_offset_m}")
        if not 0 <= self.min_overlap <= 1:
            raise ValueError(f"min_overlap: expected in [0, 1], got {self.min_overlap}")
        if not self.spacing_m > 0:
            raise ValueError(f"spacing_m: expected > 0, got {self.spacing_m}")
        if not 0 <= self.max_far_fraction <= 1:
            raise ValueError(f"max_far_fraction: expected in [0, 1], got {self.max_far_fraction}")


def voxel_keys(points: np.ndarray, spacing_m: float) -> np.ndarray:
    """(N,) int64 key of the voxel of edge ``spacing_m`` holding each point (N, 3)."""
    ijk = np.floor(np.asarray(points, dtype=np.float64) / spacing_m).astype(np.int64) + _OFF
    ijk &= _MASK
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


_D = np.array([-1, 0, 1], dtype=np.int64)
_DI, _DJ, _DK = (a.ravel() for a in np.meshgrid(_D, _D, _D, indexing="ij"))
_NEIGHBOUR_OFFSETS = (_DI << 42) + (_DJ << 21) + _DK


def _neighbours(keys: np.ndarray) -> np.ndarray:
    """(K, 27) keys of the 27-neighbourhood of each key (keys are packed so that offsets add)."""
    return keys[:, None] + _NEIGHBOUR_OFFSETS[None, :]


def fraction_touching(points: np.ndarray, other_keys: np.ndarray, spacing_m: float) -> float:
    """Fraction of ``points`` (N, 3) in or next to (26 neighbours) a voxel of edge ``spacing_m`` whose key is in the
    sorted array ``other_keys`` (:func:`voxel_keys` at that edge, made unique); 0 for no points."""
    if len(points) == 0 or len(other_keys) == 0:
        return 0.0
    from reloc.mapping import _kernels as K

    return K.count_touching(voxel_keys(points, spacing_m), other_keys, _NEIGHBOUR_OFFSETS) / len(points)


def plane_fit_from_stats(
    sums: np.ndarray, scatters: np.ndarray, counts: np.ndarray, reference_normals: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares planes from sufficient statistics.

    ``sums`` (N, 3), ``scatters`` (N, 3, 3) (sum of ``p p^T``), ``counts`` (N,). Returns ``(normals (N, 3),
    offsets (N,), centroids (N, 3), covariances (N, 4, 4))``: the normal is the smallest eigenvector of the
    centred scatter, turned to agree with ``reference_normals`` when given; the (n, d) covariance is
    ``sigma^2 (P H P)^+`` with ``H = [[S, s], [s^T, N]]`` the normal matrix of the point-to-plane fit,
    ``sigma^2`` the residual variance and ``P`` removing the unit-norm direction ``(n, 0)``.
    """
    sums = np.asarray(sums, dtype=np.float64).reshape(-1, 3)
    scatters = np.asarray(scatters, dtype=np.float64).reshape(-1, 3, 3)
    counts = np.asarray(counts, dtype=np.float64).reshape(-1)
    if np.any(counts < 3):
        raise ValueError(f"counts: expected at least 3 points per plane, got min {counts.min() if counts.size else 0}")
    c = sums / counts[:, None]
    cov = scatters / counts[:, None, None] - c[:, :, None] * c[:, None, :]
    vals, vecs = np.linalg.eigh(cov)
    normals = vecs[:, :, 0]
    if reference_normals is not None:
        flip = np.sum(normals * np.asarray(reference_normals).reshape(-1, 3), axis=1) < 0
        normals[flip] *= -1
    offsets = -np.sum(normals * c, axis=1)
    sigma2 = np.maximum(vals[:, 0], 0.0) * counts / np.maximum(counts - 3, 1)
    H = np.zeros((len(counts), 4, 4))
    H[:, :3, :3] = scatters
    H[:, :3, 3] = sums
    H[:, 3, :3] = sums
    H[:, 3, 3] = counts
    v = np.concatenate([normals, np.zeros((len(counts), 1))], axis=1)
    P = np.eye(4)[None] - v[:, :, None] * v[:, None, :]
    covs = sigma2[:, None, None] * np.linalg.pinv(P @ H @ P, hermitian=True)
    return normals, offsets, c, covs


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``u = n x e_x`` (``n x e_y`` for a normal near x) and ``v = n x u`` spanning the plane."""
    n = np.asarray(normal, dtype=np.float64)
    u = np.array([0.0, n[2], -n[1]]) if abs(n[0]) < 0.9 else np.array([-n[2], 0.0, n[0]])
    u /= np.linalg.norm(u)
    return u, np.array([n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]])


def plane_cells(points: np.ndarray, basis: tuple[np.ndarray, np.ndarray], cell_m: float) -> np.ndarray:
    """(M, 2) int64: the ``cell_m`` square of the plane spanned by ``basis`` (:func:`plane_basis`) that each of
    ``points`` (M, 3) projects into."""
    u, v = basis
    return np.floor(np.stack([points @ u, points @ v], axis=1) / cell_m).astype(np.int64)


def patch_area(points: np.ndarray, normal: np.ndarray, patch_m: float) -> float:
    """Area (m^2) of the ``patch_m`` x ``patch_m`` cells of the plane occupied by ``points`` (M, 3)."""
    if len(points) == 0:
        return 0.0
    return float(count_unique_rows(plane_cells(points, plane_basis(normal), patch_m)) * patch_m**2)


def _pinv_symmetric(a: np.ndarray, rcond: float) -> np.ndarray:
    """``np.linalg.pinv(a, rcond, hermitian=True)`` of one real symmetric matrix: the same operations (so the same
    figures, to the last bit) without the generality that makes it cost ~36 us on a 4 x 4 (here ~22)."""
    s, u = np.linalg.eigh(a)
    sgn = np.sign(s)
    s = np.abs(s)
    order = np.argsort(s)[::-1]
    sgn, s, u = sgn[order], s[order], u[:, order]
    vt = np.transpose(u * sgn[None, :]).conjugate()
    large = s > rcond * np.amax(s)
    s = np.divide(1, s, where=large, out=s)
    s[~large] = 0
    return np.matmul(np.transpose(vt), np.multiply(s[:, None], np.transpose(u)))


def _median(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a non-empty 1-D float64 array (the middle value, or the mean of the two middle
    values, as np.median forms it), without its generality (~15 us a call here)."""
    n = x.shape[0]
    k = n // 2
    part = np.partition(x, (k, -1) if n % 2 else (k - 1, k, -1))  # the last one is the largest: NaN if any
    if np.isnan(part[-1]):
        return math.nan
    return float(part[k]) if n % 2 else float((part[k - 1] + part[k]) / 2.0)


def _informations(covs: np.ndarray) -> list[np.ndarray | None]:
    """The information ``C^+`` of each plane's (n, d) covariance of ``covs`` (N, 4, 4), symmetrized, or None where a
    covariance is unusable (not finite, or zero trace); the usable ones in one stacked pseudo-inverse (per matrix the
    same figures as one at a time)."""
    covs = np.asarray(covs, dtype=np.float64)
    out: list[np.ndarray | None] = [None] * len(covs)
    if len(covs) == 0:
        return out
    usable = np.all(np.isfinite(covs), axis=(1, 2)) & (np.trace(covs, axis1=1, axis2=2) > 0)
    idx = np.flatnonzero(usable)
    if len(idx):
        sym = 0.5 * (covs[idx] + np.transpose(covs[idx], (0, 2, 1)))
        for i, info in zip(idx.tolist(), np.linalg.pinv(sym, rcond=1e-10, hermitian=True)):
            out[i] = info
    return out


def _fuse_information(info: np.ndarray, info_b: np.ndarray, n0: np.ndarray, d0: float):
    """The plane minimizing ``sum (x - x_k)^T I_k (x - x_k)`` near ``x0 = (n0, d0)``: one Gauss-Newton step in the
    tangent space of the unit normal (the direction ``(n0, 0)`` carries no information), then renormalized.
    Returns ``(n, d, covariance (4, 4))``."""
    x0 = np.concatenate([n0, [d0]])
    v = np.concatenate([n0, [0.0]])
    P = np.eye(4) - np.outer(v, v)
    A = P @ info @ P
    cov = _pinv_symmetric(A, 1e-10)
    x = x0 + cov @ (P @ (info_b - info @ x0))
    norm = float(np.linalg.norm(x[:3]))
    return x[:3] / norm, float(x[3] / norm), cov


class PlaneAccumulator:
    """Planes fused across observations, in one frame (the map, or the latest camera of a submap)."""

    def __init__(self, params: FusionParams, frame: str = "map"):
        self.params = params
        self.frame = frame
        self.normals: list[np.ndarray] = []
        self.sums: list[np.ndarray] = []
        self.scatters: list[np.ndarray] = []
        self.counts: list[int] = []
        self.seen_in: list[set] = []  # ids of the observations (add calls) that saw each plane
        self.info: list[np.ndarray | None] = []  # sum of the (n, d) information matrices, None if any was unusable
        self.info_b: list[np.ndarray] = []  # sum of I_k x_k
        self.keys: list[np.ndarray] = []  # sorted unique voxel keys of the samples
        self.vsum: list[np.ndarray] = []  # (K, 3) sum of sample points per voxel
        self.vcnt: list[np.ndarray] = []  # (K,) number of sample points per voxel
        self.offsets: list[float] = []
        self.alive: list[bool] = []
        self._obs_id = 0
        # The normals and alive flags again as arrays (rows 0 .. len(self.normals) - 1), so that association finds
        # the planes facing the same way with one product instead of a Python loop over every accumulated plane.
        self._normals_arr = np.zeros((16, 3))
        self._alive_arr = np.zeros(16, dtype=bool)

    def __len__(self) -> int:
        return int(sum(self.alive))

    # -- association --------------------------------------------------------------------------------------------

    def _touching(self, keys_q: np.ndarray, m: int) -> float:
        """Fraction of the voxels ``keys_q`` with a voxel of plane ``m`` among their 26 neighbours."""
        km = self.keys[m]
        if len(keys_q) == 0 or len(km) == 0:
            return 0.0
        from reloc.mapping import _kernels as K

        return K.count_touching(keys_q, km, _NEIGHBOUR_OFFSETS) / len(keys_q)

    def _set_normal(self, m: int, n: np.ndarray) -> None:
        self.normals[m] = n
        self._normals_arr[m] = n

    def _set_alive(self, m: int, alive: bool) -> None:
        self.alive[m] = alive
        self._alive_arr[m] = alive

    def _append_row(self, n: np.ndarray) -> None:
        m = len(self.normals)
        if m == len(self._alive_arr):
            self._normals_arr = np.concatenate([self._normals_arr, np.zeros_like(self._normals_arr)])
            self._alive_arr = np.concatenate([self._alive_arr, np.zeros_like(self._alive_arr)])
        self.normals.append(n)
        self._normals_arr[m] = n
        self.alive.append(True)
        self._alive_arr[m] = True

    def _touching_local(self, keys_q: np.ndarray, m: int, n: np.ndarray, d: float) -> float:
        """:meth:`_touching`, and 0 unless plane ``m``'s own samples where the new plane ``(n, d)`` lies (its voxels
        among the 26 neighbours of ``keys_q``) are within ``max_offset_m`` of the new plane in the median. The median
        test of :meth:`_associate` measures the new plane against plane ``m``'s fused plane only: once that plane has
        turned a little, a door in its niche passes it, and each such join turns it further."""
        from reloc.mapping import _kernels as K

        km = self.keys[m]
        if len(keys_q) == 0 or len(km) == 0:
            return 0.0
        near = np.empty(len(km), np.bool_)
        hits = K.touching_both_ways(keys_q, km, _NEIGHBOUR_OFFSETS, np.empty(len(keys_q), np.bool_), near)
        if hits == 0:
            return 0.0
        pts = self.vsum[m][near] / self.vcnt[m][near][:, None]
        if _median(np.abs(pts @ n + d)) > self.params.max_offset_m:
            return 0.0
        return hits / len(keys_q)

    def _associate(self, n: np.ndarray, d: float, pts: np.ndarray, keys_q: np.ndarray) -> list[int]:
        p = self.params
        cos_max = math.cos(p.max_angle_rad)
        out: list[int] = []
        offs: list[float] = []
        rows = len(self.normals)
        # Candidates from one product with a little slack, then the exact test of each (the same decisions as a
        # loop over every plane, to the last bit).
        near = np.flatnonzero(self._alive_arr[:rows] & (self._normals_arr[:rows] @ n >= cos_max - 1e-9))
        for m in near.tolist():
            if float(self.normals[m] @ n) < cos_max:
                continue
            dist = np.abs(pts @ self.normals[m] + self.offsets[m])
            if len(dist) == 0:
                continue
            off = _median(dist)
            if off > p.max_offset_m:
                continue
            # A plane mostly on this surface and partly on one behind it passes the median, not this.
            if p.max_far_fraction < 1 and np.count_nonzero(dist > 2 * p.max_offset_m) > p.max_far_fraction * len(dist):
                continue
            frac = self._touching_local(keys_q, m, n, d) if p.check_local else self._touching(keys_q, m)
            if frac > 0 and frac >= p.min_overlap:
                out.append(m)
                offs.append(off)
        if p.check_bridged and len(out) > 1:
            # The plane the new one fits best first: it takes the new one whether or not the others join it.
            order = sorted(range(len(out)), key=lambda i: (offs[i], i))
            out = [out[i] for i in order]
        return out

    def _merge_bridged(self, dst: int, others: list[int]) -> int:
        """Merge into ``dst`` (which has just taken in a plane associated with all of ``others``, and fits it best)
        the planes ``others``, and refit it; returns how many were merged. With ``check_bridged`` only those that
        agree with ``dst`` itself (:meth:`_agree`) are merged: a plane may touch two that are not one surface."""
        if not self.params.check_bridged:
            for other in others:
                self._merge_into(dst, other)
            self._refit(dst)
            return len(others)
        self._refit(dst)
        merged = 0
        for other in others:
            if self._agree(dst, other):
                self._merge_into(dst, other)
                self._refit(dst)
                merged += 1
        return merged

    def _agree(self, a: int, b: int) -> bool:
        """Whether accumulated planes ``a`` and ``b``, both associated with one plane, are one surface: normals within
        ``max_angle_rad`` and the samples of each within ``max_offset_m`` of the other's plane in the median (the median
        test a plane passes to join one; a wall and a tilted plane that cross only where the new plane lies do not)."""
        p = self.params
        if float(self.normals[a] @ self.normals[b]) < math.cos(p.max_angle_rad):
            return False
        for x, y in ((a, b), (b, a)):
            pts = self.vsum[y] / self.vcnt[y][:, None]
            if _median(np.abs(pts @ self.normals[x] + self.offsets[x])) > p.max_offset_m:
                return False
        return True

    # -- fusion -------------------------------------------------------------------------------------------------

    def _refit(self, m: int) -> None:
        if self.info[m] is not None:
            n, d, _ = _fuse_information(self.info[m], self.info_b[m], self.normals[m], self.offsets[m])
            self._set_normal(m, n)
            self.offsets[m] = d
            return
        n, d, _, _ = plane_fit_from_stats(self.sums[m][None], self.scatters[m][None], np.array([self.counts[m]]),
                                          self.normals[m][None])
        self._set_normal(m, n[0])
        self.offsets[m] = float(d[0])

    def _merge_into(self, dst: int, src: int) -> None:
        self.sums[dst] = self.sums[dst] + self.sums[src]
        self.scatters[dst] = self.scatters[dst] + self.scatters[src]
        if self.info[dst] is not None and self.info[src] is not None:
            self.info[dst] = self.info[dst] + self.info[src]
            self.info_b[dst] = self.info_b[dst] + self.info_b[src]
        else:
            self.info[dst] = None
        self.counts[dst] += self.counts[src]
        self.seen_in[dst] |= self.seen_in[src]
        from reloc.mapping import _kernels as K

        size = len(self.keys[dst]) + len(self.keys[src])
        keys, vs, vc = np.empty(size, np.int64), np.empty((size, 3)), np.empty(size)
        k = K.merge_voxel_sums(self.keys[dst], self.vsum[dst], self.vcnt[dst], self.keys[src], self.vsum[src],
                               self.vcnt[src], keys, vs, vc)
        self.keys[dst], self.vsum[dst], self.vcnt[dst] = keys[:k], vs[:k], vc[:k]
        self._set_alive(src, False)

    def add(self, planes: PlaneSet) -> np.ndarray:
        """Fuse ``planes`` (in this accumulator's frame); returns (N,) the accumulated plane each one went to."""
        from reloc.mapping import _kernels as K

        p = self.params
        self._obs_id += 1
        targets = np.empty(len(planes), np.int64)
        infos = _informations(planes.covariances)
        for q in range(len(planes)):
            n = planes.normals[q]
            if planes.counts[q] < 3:
                targets[q] = -1
                continue
            pts = planes.samples_of(q).astype(np.float64)
            if len(pts) == 0:
                pts = planes.centroids[q][None]
            keys_q = voxel_keys(pts, p.spacing_m)
            uk, vs, vc = np.empty(len(keys_q), np.int64), np.empty((len(keys_q), 3)), np.empty(len(keys_q))
            k = K.voxel_sums(keys_q, pts, np.argsort(keys_q, kind="stable"), uk, vs, vc)
            uk, vs, vc = uk[:k], vs[:k], vc[:k]
            hits = self._associate(n, float(planes.offsets[q]), pts, uk)
            # A new entry, then merged into the first associated plane (and every other associated plane into it).
            self._append_row(n.copy())
            self.offsets.append(float(planes.offsets[q]))
            self.sums.append(planes.sums[q].copy())
            info = infos[q]
            x = np.concatenate([n, [planes.offsets[q]]])
            self.info.append(info)
            self.info_b.append(info @ x if info is not None else np.zeros(4))
            self.scatters.append(planes.scatters[q].copy())
            self.counts.append(int(planes.counts[q]))
            self.seen_in.append({self._obs_id})
            self.keys.append(uk)
            self.vsum.append(vs)
            self.vcnt.append(vc)
            new = len(self.normals) - 1
            if hits:
                dst = hits[0]
                self._merge_into(dst, new)
                self._merge_bridged(dst, hits[1:])
                targets[q] = dst
            else:
                targets[q] = new
        return targets

    def merge_pass(self) -> int:
        """Merge accumulated planes that now associate with each other (they grew together); returns merges."""
        merges = 0
        changed = True
        while changed:
            changed = False
            for m in range(len(self.normals)):
                if not self.alive[m]:
                    continue
                pts = self.vsum[m] / self.vcnt[m][:, None]
                self._set_alive(m, False)  # do not associate with itself
                hits = self._associate(self.normals[m], self.offsets[m], pts, self.keys[m])
                self._set_alive(m, True)
                if hits:
                    dst = hits[0]
                    self._merge_into(dst, m)
                    merges += 1 + self._merge_bridged(dst, hits[1:])
                    changed = True
        return merges

    def to_planeset(self, *, gravity: np.ndarray | None, min_observations: int = 1, min_count: int = 3,
                    area_patch_m: float | None = None, gravity_tolerance_rad: float = 0.0
                    ) -> tuple[PlaneSet, np.ndarray]:
        """The accumulated planes as a PlaneSet in this frame (with ``gravity`` and its tolerance), and their
        observation counts (N,)."""
        keep = [m for m in range(len(self.normals))
                if self.alive[m] and len(self.seen_in[m]) >= min_observations and self.counts[m] >= min_count]
        if not keep:
            return (PlaneSet.empty(frame=self.frame, gravity=gravity, gravity_tolerance_rad=gravity_tolerance_rad),
                    np.zeros(0, np.int64))
        sums = np.array([self.sums[m] for m in keep])
        scat = np.array([self.scatters[m] for m in keep])
        cnt = np.array([self.counts[m] for m in keep], dtype=np.int64)
        normals, offsets, cents, covs = plane_fit_from_stats(sums, scat, cnt, np.array([self.normals[m] for m in keep]))
        for k, m in enumerate(keep):
            if self.info[m] is not None:
                normals[k], offsets[k], covs[k] = _fuse_information(self.info[m], self.info_b[m], self.normals[m],
                                                                    self.offsets[m])
        samples = [self.vsum[m] / self.vcnt[m][:, None] for m in keep]
        radii = np.array([float(np.linalg.norm(s - c, axis=1).max()) for s, c in zip(samples, cents)])
        patch = area_patch_m or self.params.spacing_m
        areas = np.array([patch_area(s, n, patch) for s, n in zip(samples, normals)])
        ptr = np.concatenate([[0], np.cumsum([len(s) for s in samples])]).astype(np.int64)
        ps = PlaneSet(
            normals=normals, offsets=offsets, centroids=cents, counts=cnt, radii=radii, areas=areas,
            covariances=covs, sums=sums, scatters=scat, sample_points=np.concatenate(samples).astype(np.float32),
            sample_ptr=ptr, frame=self.frame, gravity=gravity, gravity_tolerance_rad=gravity_tolerance_rad,
        )
        return ps, np.array([len(self.seen_in[m]) for m in keep], dtype=np.int64)
