"""Top-down view of a plane map, with a relocalized submap drawn at its estimated pose (the paper's Fig. 4).

The view looks down the map's gravity direction. Map planes are drawn from their sample points: vertical planes
(walls, doors, furniture sides) dark grey, horizontal ones (floor, ceiling, table tops) light grey beneath them, so the
walls read as lines and the floor as the room's footprint. The submap (one colour, green) is drawn at the estimated
pose; the camera at the estimate and at the ground truth (red, when known) are drawn as view wedges.
"""

from __future__ import annotations

import os

import numpy as np

from reloc.planeset import PlaneSet
from reloc.transforms import check_transform
from reloc.viz._mpl import (
    MAP_COLOR, MAP_FLOOR_COLOR, REJECTED_COLOR, SUBMAP_COLOR, TRUTH_COLOR, new_figure, save_figure,
)

__all__ = ["plot_map_topdown", "topdown_basis"]


def topdown_basis(gravity: np.ndarray | None) -> np.ndarray:
    """(2, 3) rows spanning the plane perpendicular to ``gravity`` (map x, y when gravity is -z).

    With gravity -z (or unknown) the rows are exactly map x and y, so the picture's axes are map coordinates.
    """
    g = np.array([0.0, 0.0, -1.0]) if gravity is None else np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    up = -g
    if abs(up[2]) > 0.999:
        return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) * np.array([[1.0], [np.sign(up[2])]])
    axis = np.eye(3)[0 if abs(up[0]) < 0.9 else 1]  # map x, or map y when up is near x (x has no direction left)
    e1 = axis - up * float(up @ axis)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1)])


def _split_vertical(ps: PlaneSet, gravity: np.ndarray | None, max_tilt_deg: float = 45.0) -> np.ndarray:
    """(N,) True for planes whose normal is within ``max_tilt_deg`` of horizontal (walls and sides)."""
    g = np.array([0.0, 0.0, -1.0]) if gravity is None else np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g)
    return np.abs(ps.normals @ g) < np.cos(np.deg2rad(max_tilt_deg))


def _points_of(ps: PlaneSet, mask: np.ndarray) -> np.ndarray:
    sizes = np.diff(ps.sample_ptr)
    return ps.sample_points[np.repeat(mask, sizes)].astype(np.float64)


def draw_map(ax, plane_map: PlaneSet, basis: np.ndarray, max_points: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """Scatter the map's planes seen from above: horizontal ones light grey, the rest dark grey on top.

    Returns the (N, 2) floor and wall points drawn (at most ``max_points`` each, a fixed random subset).
    """
    rng = np.random.default_rng(0)

    def thin(pts: np.ndarray) -> np.ndarray:
        return pts if len(pts) <= max_points else pts[rng.choice(len(pts), max_points, replace=False)]

    vertical = _split_vertical(plane_map, plane_map.gravity)
    floor_xy = thin(_points_of(plane_map, ~vertical)) @ basis.T
    wall_xy = thin(_points_of(plane_map, vertical)) @ basis.T
    ax.scatter(floor_xy[:, 0], floor_xy[:, 1], s=1.5, c=MAP_FLOOR_COLOR, marker="s", lw=0, rasterized=True, zorder=1)
    ax.scatter(wall_xy[:, 0], wall_xy[:, 1], s=2.0, c=MAP_COLOR, lw=0, rasterized=True, zorder=2,
               label=f"map: {len(plane_map)} planes")
    return floor_xy, wall_xy


def finish_map_axes(ax, basis: np.ndarray) -> None:
    """Equal aspect, metre labels in map coordinates, a faint grid."""
    ax.set_aspect("equal", adjustable="datalim")  # fill the axes box; the data limits grow instead
    ax.set_xlabel("map x [m]" if basis[0, 0] > 0.999 else "map, across gravity [m]")
    ax.set_ylabel("map y [m]" if basis[1, 1] > 0.999 else "-map y [m]" if basis[1, 1] < -0.999 else
                  "map, across gravity [m]")
    ax.grid(True, color="#eeeeee", lw=0.8, zorder=0)
    ax.set_axisbelow(True)


def _wedge(ax, T_map_cam: np.ndarray, basis: np.ndarray, color: str, label: str, hfov_rad: float,
           length_m: float, linestyle: str = "-") -> None:
    """Draw a camera as a view wedge (its horizontal field of view) and its position as a dot."""
    c = T_map_cam[:3, 3]
    fwd = basis @ T_map_cam[:3, 2]  # optical axis (z) seen from above
    if np.linalg.norm(fwd) < 1e-6:  # camera looking straight up/down: use its x axis for the heading
        fwd = basis @ T_map_cam[:3, 0]
    fwd = fwd / np.linalg.norm(fwd)
    p = basis @ c
    rot = lambda a: np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])  # noqa: E731
    left = p + length_m * rot(hfov_rad / 2) @ fwd
    right = p + length_m * rot(-hfov_rad / 2) @ fwd
    xy = np.array([left, p, right])
    ax.plot(xy[:, 0], xy[:, 1], color=color, lw=2.5, ls=linestyle, label=label, zorder=5)
    ax.plot([left[0], right[0]], [left[1], right[1]], color=color, lw=1.0, ls=linestyle, zorder=5)
    ax.plot(p[0], p[1], "o", color=color, ms=7, mec="white", mew=1.0, zorder=6)


def plot_map_topdown(
    plane_map: PlaneSet,
    path: str | os.PathLike,
    *,
    submap: PlaneSet | None = None,
    T_map_cam: np.ndarray | None = None,
    T_map_cam_gt: np.ndarray | None = None,
    relocalized: bool = True,
    title: str | None = None,
    hfov_deg: float = 70.0,
    width_px: int = 1000,
    height_px: int = 900,
    max_points: int = 200_000,
):
    """Save a top-down PNG of ``plane_map`` (map frame), optionally with a submap (frame of its latest camera).

    - ``T_map_cam`` (4, 4): the estimated pose of the submap's camera in the map; the submap's sample points are
      drawn there in green. When ``relocalized`` is False (a rejected query) the submap is drawn in orange at the
      ground truth instead, if known, to show what should have been found.
    - ``T_map_cam_gt`` (4, 4): ground truth, drawn as a red dashed wedge; the pose error goes in the title.
    - Axes are metres in the map frame (x right, y up when the map's gravity is -z).
    Returns the path written.
    """
    if T_map_cam is not None:
        T_map_cam = check_transform(T_map_cam, "T_map_cam")
    if T_map_cam_gt is not None:
        T_map_cam_gt = check_transform(T_map_cam_gt, "T_map_cam_gt")
    basis = topdown_basis(plane_map.gravity)
    fig = new_figure(width_px, height_px)
    ax = fig.subplots()
    floor_xy, wall_xy = draw_map(ax, plane_map, basis, max_points)

    info = []
    if submap is not None:
        pose, color, what = (T_map_cam, SUBMAP_COLOR, "submap at estimated pose") if relocalized else (
            T_map_cam_gt, REJECTED_COLOR, "rejected submap at ground truth")
        if pose is not None and len(submap):
            # Horizontal submap planes faint (they cover the floor), the rest strong: walls must line up.
            moved = submap.transformed(pose, "map")
            sub_vertical = _split_vertical(moved, plane_map.gravity)
            flat = _points_of(moved, ~sub_vertical) @ basis.T
            upright = _points_of(moved, sub_vertical) @ basis.T
            ax.scatter(flat[:, 0], flat[:, 1], s=3, c=color, alpha=0.25, lw=0, zorder=3)
            ax.scatter(upright[:, 0], upright[:, 1], s=6, c=color, lw=0, zorder=4,
                       label=f"{what}: {len(submap)} planes")
    length = 0.08 * float(np.ptp(np.concatenate([floor_xy, wall_xy]), axis=0).max()) if len(plane_map) else 1.0
    if T_map_cam_gt is not None:
        _wedge(ax, T_map_cam_gt, basis, TRUTH_COLOR, "camera, ground truth", np.deg2rad(hfov_deg), length, "--")
    if T_map_cam is not None and relocalized:
        _wedge(ax, T_map_cam, basis, SUBMAP_COLOR, "camera, estimate", np.deg2rad(hfov_deg), length)
        if T_map_cam_gt is not None:
            from reloc.transforms import pose_error

            err_m, err_deg = pose_error(T_map_cam, T_map_cam_gt)
            info.append(f"error {100 * err_m:.1f} cm, {err_deg:.2f}°")
    elif submap is not None and not relocalized:
        info.append("not relocalized")

    finish_map_axes(ax, basis)
    head = title or "map from above"
    ax.set_title(head + (f"  ({'; '.join(info)})" if info else ""))
    leg = ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=9, frameon=False, markerscale=4)
    for h in leg.legend_handles:
        if hasattr(h, "set_sizes"):
            h.set_sizes([30])
    return save_figure(fig, path)
