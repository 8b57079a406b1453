"""Ground truth of a simulated frame as a plane set, so matching can be tested without extraction.

For every scene plane labelled in the frame: the exact plane (from the scene, moved into the camera frame, normal
toward the camera) and statistics of its support, computed from the exact surface points of the labelled pixels
(each pixel's ray meeting the plane), so they do not depend on the noise draw: centroid, count, radius, area,
sufficient statistics, a voxel sample, and the (n, d) covariance a least-squares fit of the noisy points would
have under the frame's noise model.
"""

from __future__ import annotations

import numpy as np

from reloc.camera import DepthFrame
from reloc.planeset import PlaneSet
from reloc.rowkeys import count_unique_rows, first_unique_rows
from sim.noise import NoiseModel, make_noise
from sim.scenes import Scene

__all__ = ["visible_planes", "visible_planes_with_ids", "planes_in_camera", "scene_planes"]


def planes_in_camera(scene: Scene, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All scene planes in the camera frame: ``(normals (P, 3), offsets (P,))``, world normals kept as they are.

    With ``p_w = R p_c + t``: ``n_c = R^T n_w`` and ``d_c = d_w + n_w . t``.
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    return scene.normals @ R, scene.offsets + scene.normals @ t


def visible_planes(frame: DepthFrame, scene: Scene, **kwargs) -> PlaneSet:
    """The ground-truth planes seen in ``frame`` (camera frame, rows ordered by plane id); see
    :func:`visible_planes_with_ids` for the parameters. ``labels`` of the set index its rows (-1 for none)."""
    return visible_planes_with_ids(frame, scene, **kwargs)[0]


def visible_planes_with_ids(
    frame: DepthFrame,
    scene: Scene,
    *,
    min_pixels: int = 30,
    sample_spacing_m: float = 0.1,
    area_patch_m: float = 0.1,
    noise: "str | NoiseModel" = "kinect",
    min_sigma_m: float = 1e-3,
) -> tuple[PlaneSet, np.ndarray]:
    """Ground-truth :class:`PlaneSet` of ``frame`` and the (N,) scene plane ids of its rows.

    - ``frame`` must carry ``labels`` (plane ids, 0 none) and ``T_world_cam`` (as simulated frames do).
    - Planes with fewer than ``min_pixels`` labelled pixels are left out.
    - ``sample_spacing_m``: voxel size of each plane's point sample; ``area_patch_m``: patch edge for the area.
    - ``noise``: the model whose per-depth sigma (at least ``min_sigma_m``) weights the covariance.
    Gravity is the frame's ``gravity_cam``.
    """
    if frame.labels is None or frame.T_world_cam is None:
        raise ValueError("frame: expected a simulated frame with labels and T_world_cam, got "
                         f"labels={'set' if frame.labels is not None else None}, "
                         f"T_world_cam={'set' if frame.T_world_cam is not None else None}")
    if min_pixels < 3:
        raise ValueError(f"min_pixels: expected >= 3, got {min_pixels}")
    model = make_noise(noise)
    intr = frame.intrinsics
    labels = np.asarray(frame.labels)
    n_cam, d_cam = planes_in_camera(scene, frame.T_world_cam)

    ids, counts = np.unique(labels[labels > 0], return_counts=True)
    ids = ids[counts >= min_pixels]
    rows = [scene.index_of(int(i)) for i in ids]

    index_image = -np.ones(labels.shape, dtype=np.int32)
    normals, offsets, centroids, cnts, radii, areas, covs, sums, scatters = ([] for _ in range(9))
    samples, sizes = [], []
    vv, uu = np.nonzero(labels > 0)
    lab_flat = labels[vv, uu]
    focal = abs(float(intr.fx))
    radius = model.radius_map(intr) if model.name == "tof" else None
    for k, (pid, row) in enumerate(zip(ids, rows)):
        sel = lab_flat == pid
        v, u = vv[sel], uu[sel]
        index_image[v, u] = k
        n, d = n_cam[row].copy(), float(d_cam[row])
        if d < 0:  # orient toward the camera (the origin): n . 0 + d > 0
            n, d = -n, -d
        rays = np.column_stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(len(u))])
        z = -d / (rays @ n)
        pts = rays * z[:, None]
        c = pts.mean(axis=0)
        normals.append(n)
        offsets.append(d)
        centroids.append(c)
        cnts.append(len(u))
        radii.append(float(np.linalg.norm(pts - c, axis=1).max()))
        areas.append(_patch_area(pts, n, area_patch_m))
        sums.append(pts.sum(axis=0))
        scatters.append(pts.T @ pts)
        sigma = np.maximum(model.sigma_m(z, radius[v, u] if radius is not None else 0.0, focal), min_sigma_m)
        covs.append(_plane_covariance(pts, n, sigma))
        s = _voxel_sample(pts, sample_spacing_m)
        samples.append(s)
        sizes.append(len(s))

    if not len(ids):
        ps = PlaneSet.empty(frame="cam", gravity=frame.gravity_cam, labels=index_image)
        return ps, np.zeros(0, dtype=np.int32)
    ps = PlaneSet(
        normals=np.array(normals), offsets=np.array(offsets), centroids=np.array(centroids),
        counts=np.array(cnts, dtype=np.int64), radii=np.array(radii), areas=np.array(areas),
        covariances=np.array(covs), sums=np.array(sums), scatters=np.array(scatters),
        sample_points=np.concatenate(samples).astype(np.float32),
        sample_ptr=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        frame="cam", gravity=frame.gravity_cam, labels=index_image,
    )
    return ps, ids.astype(np.int32)


def scene_planes(scene: Scene, *, sample_spacing_m: float = 0.1) -> tuple[PlaneSet, np.ndarray]:
    """Every plane of the scene as a world-frame PlaneSet (frame "map") with the (P,) plane ids: the exact map.

    Statistics come from the polygons sampled on a ``sample_spacing_m`` grid; covariances are left at zero
    (exact planes); gravity is world -z.
    """
    normals, offsets, centroids, cnts, radii, areas, sums, scatters, samples, sizes = ([] for _ in range(10))
    poly_area = scene.plane_areas()
    for row in range(scene.n_planes):
        n = scene.normals[row]
        pts = np.concatenate([_sample_polygon(p, sample_spacing_m) for p in scene.polygons_of(row)])
        c = pts.mean(axis=0)
        normals.append(n)
        offsets.append(scene.offsets[row])
        centroids.append(c)
        cnts.append(len(pts))
        radii.append(float(np.linalg.norm(pts - c, axis=1).max()))
        areas.append(poly_area[row])
        sums.append(pts.sum(axis=0))
        scatters.append(pts.T @ pts)
        samples.append(pts)
        sizes.append(len(pts))
    ps = PlaneSet(
        normals=np.array(normals), offsets=np.array(offsets), centroids=np.array(centroids),
        counts=np.array(cnts, dtype=np.int64), radii=np.array(radii), areas=np.array(areas),
        covariances=np.zeros((scene.n_planes, 4, 4)), sums=np.array(sums), scatters=np.array(scatters),
        sample_points=np.concatenate(samples).astype(np.float32),
        sample_ptr=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        frame="map", gravity=np.array([0.0, 0.0, -1.0]),
    )
    return ps, scene.plane_ids.copy()


def _plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


def _patch_area(pts: np.ndarray, n: np.ndarray, patch_m: float) -> float:
    """Area as the number of occupied ``patch_m`` squares of the plane times their area."""
    e1, e2 = _plane_basis(n)
    cells = np.floor(np.column_stack([pts @ e1, pts @ e2]) / patch_m).astype(np.int64)
    return float(count_unique_rows(cells)) * patch_m * patch_m


def _voxel_sample(pts: np.ndarray, spacing_m: float) -> np.ndarray:
    """One point (the first) per occupied ``spacing_m`` voxel: exact surface points, deterministic order."""
    keys = np.floor(pts / spacing_m).astype(np.int64)
    return pts[np.sort(first_unique_rows(keys))]


def _plane_covariance(pts: np.ndarray, n: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(4, 4) covariance of (n, d) for a weighted least-squares fit: the pseudo-inverse of the information
    ``sum q q^T / sigma^2`` (``q = (p, 1)``) restricted to the directions that keep ``n`` unit."""
    q = np.column_stack([pts, np.ones(len(pts))])
    w = 1.0 / (sigma * sigma)
    info = (q * w[:, None]).T @ q
    u = np.append(n, 0.0)
    P = np.eye(4) - np.outer(u, u)
    cov = np.linalg.pinv(P @ info @ P, rcond=1e-12, hermitian=True)
    return 0.5 * (cov + cov.T)


def _sample_polygon(poly: np.ndarray, spacing_m: float) -> np.ndarray:
    """Grid points (spacing ``spacing_m``) inside a convex planar polygon, at least its vertices' centroid."""
    v0 = poly[0]
    n = np.cross(poly[1] - v0, poly[2] - v0)
    for k in range(3, len(poly)):
        if np.linalg.norm(n) > 1e-12:
            break
        n = np.cross(poly[1] - v0, poly[k] - v0)
    n /= np.linalg.norm(n)
    e1, e2 = _plane_basis(n)
    uv = np.column_stack([(poly - v0) @ e1, (poly - v0) @ e2])
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    gu = np.arange(lo[0] + spacing_m / 2, hi[0], spacing_m)
    gv = np.arange(lo[1] + spacing_m / 2, hi[1], spacing_m)
    G = np.stack(np.meshgrid(gu, gv, indexing="ij"), axis=-1).reshape(-1, 2)
    inside = np.ones(len(G), dtype=bool)
    m = len(uv)
    area2 = sum(uv[i, 0] * uv[(i + 1) % m, 1] - uv[(i + 1) % m, 0] * uv[i, 1] for i in range(m))
    sgn = 1.0 if area2 > 0 else -1.0
    for i in range(m):
        a, b = uv[i], uv[(i + 1) % m]
        cross = (b[0] - a[0]) * (G[:, 1] - a[1]) - (b[1] - a[1]) * (G[:, 0] - a[0])
        inside &= sgn * cross >= -1e-12
    G = G[inside]
    if len(G) == 0:
        G = uv.mean(axis=0, keepdims=True)
    return v0 + G[:, :1] * e1 + G[:, 1:] * e2
