"""A slow, obviously correct NumPy renderer: the reference the numba kernels are tested and benchmarked against."""

from __future__ import annotations

import numpy as np

from reloc.camera import Intrinsics
from sim.ground_truth import planes_in_camera
from sim.scenes import Scene

__all__ = ["reference_render"]


def _rays(intr: Intrinsics) -> np.ndarray:
    """(H, W, 3) ray directions with z = 1 at pixel centres."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    return np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(u.shape)], axis=-1)


def reference_render(scene: Scene, intr: Intrinsics, T_world_cam: np.ndarray, near: float = 0.05):
    """``(depth_m, labels)`` as :func:`sim.render.render` gives them, computed the slow, obvious way: for every
    polygon, every pixel's ray meets its plane and a 3-D inside test decides; clutter is solved analytically."""
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    rays = _rays(intr).reshape(-1, 3)
    best = np.full(len(rays), np.inf)
    lab = np.zeros(len(rays), np.int32)
    n_cam, d_cam = planes_in_camera(scene, T_world_cam)
    for q in range(scene.n_polygons):
        row = scene.poly_plane[q]
        n, d = n_cam[row], d_cam[row]
        verts = (scene.poly_vertices[scene.poly_ptr[q] : scene.poly_ptr[q + 1]] - t) @ R  # camera frame
        with np.errstate(divide="ignore", invalid="ignore"):
            z = -d / (rays @ n)
        p = rays * z[:, None]
        inside = np.ones(len(rays), bool)
        sides = []
        for i in range(len(verts)):
            e = verts[(i + 1) % len(verts)] - verts[i]
            sides.append(np.cross(e, p - verts[i]) @ n)
        sides = np.array(sides)
        tol = 1e-9
        inside = np.all(sides >= -tol, axis=0) | np.all(sides <= tol, axis=0)
        ok = inside & np.isfinite(z) & (z > near) & (z < best)
        best[ok] = z[ok]
        lab[ok] = scene.plane_ids[row]
    centre = t
    dirs = rays @ R.T  # world directions, parameter = camera z
    for x, y, z0, z1, r in scene.cylinders:
        q = centre[:2] - (x, y)
        a = (dirs[:, :2] ** 2).sum(1)
        b = 2 * dirs[:, :2] @ q
        c = q @ q - r * r
        disc = b * b - 4 * a * c
        with np.errstate(invalid="ignore", divide="ignore"):
            tt = (-b - np.sqrt(disc)) / (2 * a)
            hz = centre[2] + tt * dirs[:, 2]
            side = np.where((disc >= 0) & (tt > near) & (hz >= z0) & (hz <= z1), tt, np.inf)
            caps = []
            for cz in (z0, z1):
                tc = (cz - centre[2]) / dirs[:, 2]
                h = centre[:2] + tc[:, None] * dirs[:, :2] - (x, y)
                caps.append(np.where((tc > near) & ((h**2).sum(1) <= r * r), tc, np.inf))
        hit = np.minimum(side, np.minimum(*caps))
        ok = hit < best
        best[ok] = hit[ok]
        lab[ok] = 0
    for x, y, z, r in scene.spheres:
        q = centre - (x, y, z)
        a = (dirs**2).sum(1)
        b = 2 * dirs @ q
        c = q @ q - r * r
        disc = b * b - 4 * a * c
        with np.errstate(invalid="ignore"):
            tt = (-b - np.sqrt(disc)) / (2 * a)
        ok = (disc >= 0) & (tt > near) & (tt < best)
        best[ok] = tt[ok]
        lab[ok] = 0
    best[~np.isfinite(best)] = np.nan
    return best.reshape(intr.shape).astype(np.float32), lab.reshape(intr.shape)
