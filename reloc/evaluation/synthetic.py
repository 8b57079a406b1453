"""Plane sets of rectangle scenes, without rendering: exact inputs for testing and benchmarking matching alone.

A scene is a list of :class:`Rect` (world frame, z up). :func:`view_planes` gives what a camera at ``T_world_cam``
sees of it as a :class:`~reloc.planeset.PlaneSet` in the camera frame: the part of each rectangle facing the camera
inside its field of view and range (no occlusion), sampled on a grid, with optional noise on the points and on the
plane parameters. :func:`scene_planes` gives the whole scene as a map plane set. The full simulator (``sim``)
renders depth images; this module exists so the matcher can be tested with exact, cheap inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reloc.planeset import PlaneSet
from reloc.transforms import invert, rotation_from_axis_angle, transform_from_rotation_translation

__all__ = ["Rect", "box", "room", "furnished_room", "scene_planes", "view_planes", "look_at", "planes_from_points"]


@dataclass(frozen=True)
class Rect:
    """A rectangle: ``center`` (3,), unit ``normal`` (the visible side), unit in-plane ``u``, half sizes."""

    center: tuple
    normal: tuple
    u: tuple
    half_u: float
    half_v: float

    def grid(self, spacing: float) -> np.ndarray:
        """(M, 3) points on a grid of ``spacing`` covering the rectangle."""
        c, n, u = (np.asarray(x, dtype=np.float64) for x in (self.center, self.normal, self.u))
        v = np.cross(n, u)
        nu = max(1, int(round(2 * self.half_u / spacing)))
        nv = max(1, int(round(2 * self.half_v / spacing)))
        a = (np.arange(nu) + 0.5) / nu * 2 * self.half_u - self.half_u
        b = (np.arange(nv) + 0.5) / nv * 2 * self.half_v - self.half_v
        A, B = np.meshgrid(a, b, indexing="ij")
        return c + A.reshape(-1, 1) * u + B.reshape(-1, 1) * v


def box(center_xy, size_xyz, *, z0: float = 0.0, yaw_rad: float = 0.0, top: bool = True) -> list[Rect]:
    """A box standing on the floor: its top (facing up) and four sides (facing out)."""
    cx, cy = center_xy
    sx, sy, sz = size_xyz
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    ex, ey = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    z = np.array([0.0, 0.0, 1.0])
    mid = np.array([cx, cy, z0 + sz / 2])
    out = []
    if top:
        out.append(Rect(tuple(mid + z * sz / 2), tuple(z), tuple(ex), sx / 2, sy / 2))
    for sign in (1, -1):
        out.append(Rect(tuple(mid + sign * ex * sx / 2), tuple(sign * ex), tuple(ey * sign), sy / 2, sz / 2))
        out.append(Rect(tuple(mid + sign * ey * sy / 2), tuple(sign * ey), tuple(-ex * sign), sx / 2, sz / 2))
    return out


def room(width: float, depth: float, height: float, *, origin=(0.0, 0.0), ceiling: bool = True) -> list[Rect]:
    """Floor, optional ceiling and four walls (normals inward) of the room ``origin + [0, width] x [0, depth]``."""
    ox, oy = origin
    cx, cy = ox + width / 2, oy + depth / 2
    rects = [Rect((cx, cy, 0.0), (0, 0, 1), (1, 0, 0), width / 2, depth / 2)]
    if ceiling:
        rects.append(Rect((cx, cy, height), (0, 0, -1), (1, 0, 0), width / 2, depth / 2))
    h = height / 2
    rects += [
        Rect((ox, cy, h), (1, 0, 0), (0, 1, 0), depth / 2, h),
        Rect((ox + width, cy, h), (-1, 0, 0), (0, -1, 0), depth / 2, h),
        Rect((cx, oy, h), (0, 1, 0), (-1, 0, 0), width / 2, h),
        Rect((cx, oy + depth, h), (0, -1, 0), (1, 0, 0), width / 2, h),
    ]
    return rects


def furnished_room(kind: str = "living", origin=(0.0, 0.0)) -> list[Rect]:
    """A 6 x 5 x 2.6 m room with furniture; ``kind`` picks one of a few fixed layouts ("living", "office",
    "meeting", "symmetric")."""
    ox, oy = origin
    if kind == "symmetric":
        # A square room with a point-symmetric layout: 180 degree rotation about its centre maps it onto itself.
        rects = room(5.0, 5.0, 2.6, origin=origin)
        rects += box((ox + 1.2, oy + 1.2), (0.8, 0.8, 0.75))
        rects += box((ox + 3.8, oy + 3.8), (0.8, 0.8, 0.75))
        return rects
    rects = room(6.0, 5.0, 2.6, origin=origin)
    if kind == "living":
        rects += box((ox + 1.5, oy + 1.0), (2.0, 0.9, 0.45))  # sofa
        rects += box((ox + 1.5, oy + 2.4), (1.0, 0.6, 0.4))  # coffee table
        rects += box((ox + 5.5, oy + 3.5), (0.5, 1.6, 1.8))  # shelf
        rects += box((ox + 4.0, oy + 0.4), (1.2, 0.5, 0.7))  # sideboard
    elif kind == "office":
        rects += box((ox + 1.0, oy + 4.2), (1.6, 0.8, 0.74))
        rects += box((ox + 3.5, oy + 4.2), (1.6, 0.8, 0.74))
        rects += box((ox + 5.6, oy + 1.5), (0.6, 1.2, 1.2), yaw_rad=0.0)
        rects += box((ox + 2.5, oy + 1.0), (0.5, 0.5, 1.9))
    elif kind == "meeting":
        rects += box((ox + 3.0, oy + 2.5), (3.0, 1.2, 0.75))
        rects += box((ox + 0.4, oy + 4.0), (0.5, 1.5, 1.1))
    else:
        raise ValueError(f"kind: expected 'living', 'office', 'meeting' or 'symmetric', got {kind!r}")
    return rects


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of a camera (optical frame: x right, y down, z forward) at ``eye`` looking at ``target``,
    its image's up toward ``up``; looking straight along ``up`` (down at the floor, say), its x is the world axis
    least aligned with the view, made square to it."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    if not np.linalg.norm(z) > 0:
        raise ValueError(f"look_at: eye and target are the same point, {eye.tolist()}")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9 * max(1.0, float(np.linalg.norm(up))):
        axis = np.eye(3)[int(np.argmin(np.abs(z)))]
        x = axis - z * float(z @ axis)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return transform_from_rotation_translation(np.stack([x, y, z], axis=1), eye)


def planes_from_points(
    pieces: list[np.ndarray],
    normals: np.ndarray,
    offsets: np.ndarray,
    *,
    spacing: float,
    frame: str,
    gravity: np.ndarray | None,
    points_per_sample: int = 25,
) -> PlaneSet:
    """A PlaneSet from sampled points per plane (each sample standing for ``points_per_sample`` points)."""
    n = len(pieces)
    counts = np.array([len(p) * points_per_sample for p in pieces], dtype=np.int64)
    centroids = np.array([p.mean(axis=0) for p in pieces]).reshape(n, 3)
    radii = np.array([np.linalg.norm(p - c, axis=1).max() for p, c in zip(pieces, centroids)])
    areas = np.array([len(p) * spacing**2 for p in pieces])
    sums = np.array([p.sum(axis=0) * points_per_sample for p in pieces]).reshape(n, 3)
    scatters = np.array([p.T @ p * points_per_sample for p in pieces]).reshape(n, 3, 3)
    covs = np.tile(np.diag([1e-6, 1e-6, 1e-6, 1e-6]), (n, 1, 1))
    ptr = np.concatenate([[0], np.cumsum([len(p) for p in pieces])]).astype(np.int64)
    pts = np.concatenate(pieces).astype(np.float32) if n else np.zeros((0, 3), np.float32)
    return PlaneSet(
        normals=normals, offsets=offsets, centroids=centroids, counts=counts, radii=radii, areas=areas,
        covariances=covs, sums=sums, scatters=scatters, sample_points=pts, sample_ptr=ptr, frame=frame,
        gravity=gravity,
    )


def scene_planes(rects: list[Rect], *, spacing: float = 0.1) -> PlaneSet:
    """The whole scene as a map plane set (frame "map", gravity -z)."""
    pieces = [r.grid(spacing) for r in rects]
    normals = np.array([r.normal for r in rects], dtype=np.float64)
    offsets = -np.sum(normals * np.array([r.center for r in rects]), axis=1)
    return planes_from_points(pieces, normals, offsets, spacing=spacing, frame="map", gravity=np.array([0, 0, -1.0]))


def view_planes(
    rects: list[Rect],
    T_world_cam: np.ndarray,
    *,
    spacing: float = 0.1,
    hfov_deg: float = 70.0,
    vfov_deg: float = 55.0,
    max_range_m: float = 6.0,
    min_points: int = 20,
    point_noise_m: float = 0.0,
    normal_noise_deg: float = 0.0,
    offset_noise_m: float = 0.0,
    rng: np.random.Generator | None = None,
) -> PlaneSet:
    """What a camera at ``T_world_cam`` sees: a PlaneSet in its frame (gravity from the pose), planes with fewer
    than ``min_points`` visible samples dropped. Noise is Gaussian: on each sample along the normal, and on each
    plane's normal direction and offset."""
    rng = rng or np.random.default_rng(0)
    T_cam_world = invert(T_world_cam)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    eye = T_world_cam[:3, 3]
    th, tv = math.tan(math.radians(hfov_deg / 2)), math.tan(math.radians(vfov_deg / 2))
    pieces, normals, offsets = [], [], []
    for r in rects:
        n_w = np.asarray(r.normal, dtype=np.float64)
        pts_w = r.grid(spacing)
        if np.dot(eye - np.asarray(r.center), n_w) <= 0:
            continue  # back side
        pc = pts_w @ R.T + t
        z = pc[:, 2]
        vis = (z > 0.3) & (np.linalg.norm(pc, axis=1) < max_range_m)
        vis &= (np.abs(pc[:, 0]) <= th * z) & (np.abs(pc[:, 1]) <= tv * z)
        if vis.sum() < min_points:
            continue
        n_c = R @ n_w
        d_c = -float(n_c @ (R @ np.asarray(r.center) + t))
        pc = pc[vis]
        if point_noise_m > 0:
            pc = pc + rng.normal(0, point_noise_m, size=(len(pc), 1)) * n_c
        if normal_noise_deg > 0:
            axis = rng.normal(size=3)
            axis -= axis @ n_c * n_c
            axis /= np.linalg.norm(axis)
            ang = math.radians(rng.normal(0, normal_noise_deg))
            n_c = rotation_from_axis_angle(axis * ang) @ n_c
            d_c = -float(n_c @ pc.mean(axis=0))
        if offset_noise_m > 0:
            d_c += float(rng.normal(0, offset_noise_m))
        pieces.append(pc)
        normals.append(n_c)
        offsets.append(d_c)
    gravity = R @ np.array([0.0, 0.0, -1.0])
    if not pieces:
        return PlaneSet.empty(frame="cam", gravity=gravity)
    return planes_from_points(pieces, np.array(normals), np.array(offsets), spacing=spacing, frame="cam",
                              gravity=gravity)
