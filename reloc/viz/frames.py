"""A depth frame with its extracted planes: depth on the left, planes coloured with their normals on the right."""

from __future__ import annotations

import os

import numpy as np

from reloc.camera import DepthFrame
from reloc.planeset import PlaneSet
from reloc.viz._mpl import new_figure, plane_colors, save_figure

__all__ = ["plot_frame_planes"]


def _project(points_cam: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame points to (N, 2) pixel coordinates (u, v); NaN behind the camera."""
    z = points_cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * points_cam[:, 0] / z + K[0, 2]
        v = K[1, 1] * points_cam[:, 1] / z + K[1, 2]
    uv = np.column_stack([u, v])
    uv[z <= 1e-6] = np.nan
    return uv


def _anchor_points(planes: PlaneSet, labels: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 3) a point on each plane where its normal is drawn: on the plane's own pixels, nearest its centroid.

    The centroid itself can fall outside the plane's pixels (a wall seen on both sides of a doorway), so the arrow
    starts at the labelled pixel nearest the projected centroid, lifted onto the plane along its viewing ray.
    Planes without labelled pixels keep their centroid.
    """
    anchors = planes.centroids.copy()
    uv_c = _project(planes.centroids, K)
    for i in range(len(planes)):
        vs, us = np.nonzero(labels == i)
        if vs.size == 0 or not np.all(np.isfinite(uv_c[i])):
            continue
        j = int(np.argmin((us - uv_c[i, 0]) ** 2 + (vs - uv_c[i, 1]) ** 2))
        ray = np.array([(us[j] - K[0, 2]) / K[0, 0], (vs[j] - K[1, 2]) / K[1, 1], 1.0])
        denom = float(planes.normals[i] @ ray)
        if abs(denom) > 1e-9:
            t = -float(planes.offsets[i]) / denom
            if t > 0:
                anchors[i] = t * ray
    return anchors


def plot_frame_planes(
    frame: DepthFrame,
    planes: PlaneSet,
    path: str | os.PathLike,
    *,
    title: str | None = None,
    normal_length_m: float = 0.4,
    max_legend: int = 14,
    width_px: int = 1500,
    height_px: int = 560,
):
    """Save a PNG of ``frame``'s depth and of ``planes`` (camera frame) coloured over it, with their normals.

    - ``planes.labels`` (H, W) int32 gives the plane index of each pixel (-1 none), as extraction returns it.
    - Each normal is drawn as an arrow from the plane's centroid (``normal_length_m`` long in 3-D, projected);
      a normal that points almost straight at the camera is drawn as a circled dot (the arrow seen head-on).
    - A legend lists each plane's index, normal (camera frame) and offset, up to ``max_legend`` planes.
    Returns the path written.
    """
    depth = np.asarray(frame.depth_m, dtype=np.float32)
    if planes.labels is None:
        raise ValueError("planes: expected a plane set of one frame with labels (H, W), got labels=None")
    labels = np.asarray(planes.labels)
    if labels.shape != depth.shape:
        raise ValueError(f"planes.labels: expected shape {depth.shape} (the depth image), got {labels.shape}")
    if planes.frame != "cam":
        raise ValueError(f"planes.frame: expected 'cam' (planes of this frame), got {planes.frame!r}")

    valid = np.isfinite(depth) & (depth > 0)
    n = len(planes)
    colors = plane_colors(n)
    fig = new_figure(width_px, height_px)
    ax_depth, ax_planes = fig.subplots(1, 2)

    # Left: depth in metres (invalid pixels white).
    shown = np.where(valid, depth, np.nan)
    vmax = float(np.nanpercentile(shown, 99)) if valid.any() else 1.0
    im = ax_depth.imshow(shown, cmap="viridis", vmin=0.0, vmax=max(vmax, 1e-3), interpolation="nearest")
    cb = fig.colorbar(im, ax=ax_depth, shrink=0.85, pad=0.01)
    cb.set_label("depth [m]")
    ax_depth.set_title(f"depth frame {frame.seq} ({100 * valid.mean():.0f}% valid pixels)")

    # Right: grey depth with each plane's pixels coloured, then normals.
    grey = np.where(valid, 0.35 + 0.55 * np.clip(depth / max(vmax, 1e-3), 0, 1), 1.0)
    rgb = np.repeat(grey[:, :, None], 3, axis=2)
    on = labels >= 0
    if n:
        idx = np.clip(labels, 0, n - 1)
        rgb[on] = 0.25 * rgb[on] + 0.75 * colors[idx[on]]
    ax_planes.imshow(rgb, interpolation="nearest")
    K = frame.intrinsics.K
    if n:
        anchors = _anchor_points(planes, labels, K)
        uv0 = _project(anchors, K)
        uv1 = _project(anchors + normal_length_m * planes.normals, K)
        h, w = depth.shape
        head_on_px = 0.04 * max(h, w)
        for i in range(n):
            (u0, v0), (u1, v1) = uv0[i], uv1[i]
            if not np.all(np.isfinite([u0, v0])) or not (-0.5 <= u0 < w and -0.5 <= v0 < h):
                continue
            if not np.all(np.isfinite([u1, v1])) or np.hypot(u1 - u0, v1 - v0) < head_on_px:
                ax_planes.plot(u0, v0, "o", ms=11, mfc="white", mec="black", mew=1.5)
                ax_planes.plot(u0, v0, "o", ms=3, color="black")
            else:
                ax_planes.annotate(
                    "", xy=(u1, v1), xytext=(u0, v0),
                    arrowprops=dict(arrowstyle="-|>", color="black", lw=2.0, mutation_scale=16, shrinkA=0, shrinkB=0),
                )
            ax_planes.text(u0 + 6, v0 - 6, str(i), fontsize=10, weight="bold", color="black",
                           bbox=dict(boxstyle="round,pad=0.15", fc=colors[i], ec="none", alpha=0.9))
    ax_planes.set_xlim(-0.5, depth.shape[1] - 0.5)
    ax_planes.set_ylim(depth.shape[0] - 0.5, -0.5)
    ax_planes.set_title(title or f"{n} planes and their normals ({100 * on.mean():.0f}% of pixels on a plane)")
    for ax in (ax_depth, ax_planes):
        ax.set_xticks([])
        ax.set_yticks([])

    if n:
        from matplotlib.patches import Patch

        handles = [
            Patch(color=colors[i], label=f"{i}: n=({planes.normals[i, 0]:+.2f},{planes.normals[i, 1]:+.2f},"
                                         f"{planes.normals[i, 2]:+.2f}) d={planes.offsets[i]:+.2f} m")
            for i in range(min(n, max_legend))
        ]
        if n > max_legend:
            handles.append(Patch(color="white", label=f"... {n - max_legend} more"))
        ax_planes.legend(handles=handles, loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8,
                         title="plane: normal (camera), offset", title_fontsize=8, frameon=False)
    return save_figure(fig, path)
