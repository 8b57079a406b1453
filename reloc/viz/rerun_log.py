"""Frames, planes and poses for the Rerun viewer (optional: ``pip install rerun-sdk``, imported lazily).

A recording (``.rrd``, open with ``rerun FILE.rrd``) holds, in the map frame (z up): the map's plane samples coloured
by plane, a depth frame with its plane labels and normals under its camera, and per query (timeline ``query``) the
submap at its estimated camera pose beside the ground-truth camera.
"""

from __future__ import annotations

import os

import numpy as np

from reloc.camera import DepthFrame
from reloc.planeset import PlaneSet

__all__ = ["require_rerun", "open_recording", "log_map", "log_frame", "log_query"]


def require_rerun():
    """Import rerun or raise an ImportError that says how to install it."""
    try:
        import rerun
    except ImportError as exc:
        raise ImportError("--rerun needs the rerun-sdk package: pip install rerun-sdk (then open the file with "
                          "rerun FILE.rrd)") from exc
    return rerun


def open_recording(path: str | os.PathLike):
    """A recording stream writing to ``path`` (.rrd), the map frame z up."""
    rr = require_rerun()
    if not str(path).endswith(".rrd"):
        raise ValueError(f"path: expected a .rrd file name, got {str(path)!r}")
    rec = rr.RecordingStream("voxelplane-reloc")
    rec.save(str(path))
    rec.log("map", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


def _colors(n: int) -> np.ndarray:
    """(n, 3) uint8 colours, the pictures' tab20 order."""
    from reloc.viz._mpl import plane_colors

    return (255 * plane_colors(n)).astype(np.uint8)


def _points_by_plane(ps: PlaneSet) -> tuple[np.ndarray, np.ndarray]:
    sizes = np.diff(ps.sample_ptr)
    return ps.sample_points.astype(np.float32), np.repeat(np.arange(len(ps)), sizes)


def _transform(rr, T: np.ndarray):
    T = np.asarray(T, dtype=np.float64)
    return rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3])


def log_map(rec, plane_map: PlaneSet, entity: str = "map/planes") -> None:
    """The map's plane samples (map frame), one colour per plane, as static data."""
    rr = require_rerun()
    pts, idx = _points_by_plane(plane_map)
    rec.log(entity, rr.Points3D(pts, colors=_colors(len(plane_map))[idx], radii=0.01), static=True)


def log_frame(rec, frame: DepthFrame, planes: PlaneSet, entity: str = "map/frame") -> None:
    """A depth frame under its camera (at ``frame.T_world_cam`` when known): depth image, plane labels and each
    plane's normal as an arrow from its centroid (camera frame)."""
    rr = require_rerun()
    if frame.T_world_cam is not None:
        rec.log(entity, _transform(rr, frame.T_world_cam), static=True)
    h, w = frame.depth_m.shape
    rec.log(f"{entity}/camera", rr.Pinhole(image_from_camera=frame.intrinsics.K, resolution=[w, h],
                                           camera_xyz=rr.ViewCoordinates.RDF), static=True)
    depth = np.nan_to_num(np.asarray(frame.depth_m, dtype=np.float32), nan=0.0)
    rec.log(f"{entity}/camera/depth", rr.DepthImage(depth, meter=1.0), static=True)
    if planes.labels is not None:
        rec.log(f"{entity}/camera/planes", rr.SegmentationImage((planes.labels + 1).astype(np.uint16)), static=True)
    if len(planes):
        rec.log(f"{entity}/normals", rr.Arrows3D(origins=planes.centroids, vectors=0.3 * planes.normals,
                                                  colors=_colors(len(planes)),
                                                  labels=[str(i) for i in range(len(planes))]), static=True)


def log_query(rec, index: int, name: str, submap: PlaneSet, status: str, T_map_cam: np.ndarray | None,
              T_map_cam_gt: np.ndarray | None) -> None:
    """One query on the ``query`` timeline: its submap (green) at the estimated pose, or (orange) at the ground truth
    when it was not relocalized; the ground-truth camera in red."""
    rr = require_rerun()
    rec.set_time("query", sequence=int(index))
    pose = T_map_cam if status == "relocalized" else T_map_cam_gt
    color = [26, 152, 80] if status == "relocalized" else [224, 130, 20]
    rec.log("map/query", rr.TextDocument(f"{name}: {status}"))
    if pose is not None:
        rec.log("map/query/estimate", _transform(rr, pose))
        pts, _ = _points_by_plane(submap)
        rec.log("map/query/estimate/submap", rr.Points3D(pts, colors=color, radii=0.015))
    if T_map_cam_gt is not None:
        rec.log("map/query/truth", _transform(rr, T_map_cam_gt))
        rec.log("map/query/truth/axes", rr.Arrows3D(origins=np.zeros((3, 3)), vectors=0.3 * np.eye(3),
                                                    colors=[[214, 39, 40], [214, 39, 40], [120, 0, 0]]))
