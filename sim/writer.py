"""Write simulated frames as a TUM RGB-D style sequence with ground truth.

Layout of ``out_dir``:

- ``depth/<t>.png``: uint16 depth, ``raw = round(depth_m * depth_scale)``, 0 = no measurement; ``<t>`` is the
  timestamp in seconds with 6 decimals (as TUM RGB-D names its files).
- ``depth.txt``: ``timestamp filename`` per frame (TUM header comments).
- ``groundtruth.txt``: ``timestamp tx ty tz qx qy qz qw``, camera (optical frame) to world.
- ``gravity.txt``: ``timestamp gx gy gz``, the exact gravity direction (unit, pointing down) in the camera frame, as
  an IMU would give it (``drivers.readers`` reads it into ``DepthFrame.gravity_cam``); one row per frame that has
  one (the simulator's frames always do).
- ``labels/<t>.png`` and ``labels.txt``: uint16 plane id per pixel, 0 for none.
- ``camera.yaml``: fx, fy, cx, cy, width, height, depth_scale.
- ``planes.json``: every plane of the scene in the world frame: id, kind, normal, offset, polygons, bounding box,
  area; the clutter; the conventions.
- ``sim.json``: how the sequence was made (scene, seeds, noise parameters, trajectory), for provenance.

Every file is written atomically. The world frame is the scene's, so sequences of one scene share it whatever the
trajectory or seed.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterable

import numpy as np
import yaml

from reloc.atomic import atomic_write_text
from reloc.camera import DepthFrame
from reloc.transforms import tum_from_transform
from sim.scenes import Scene

__all__ = ["write_sequence", "WriteSummary", "planes_json", "stamp_name"]


@dataclass(frozen=True)
class WriteSummary:
    out_dir: str
    n_frames: int
    width: int
    height: int
    depth_scale: float
    n_scene_planes: int
    valid_fraction: float  # mean fraction of pixels with a measurement
    labelled_fraction: float  # mean fraction of pixels labelled with a plane
    visible_planes_median: float  # median number of distinct plane ids per frame
    unrepresentable_pixels: int  # depths beyond the uint16 range at this depth_scale, written as 0
    seconds: float


def stamp_name(stamp_ns: int) -> str:
    """TUM-style timestamp text: seconds with 6 decimals (``1.033333``)."""
    return f"{stamp_ns // 1_000_000_000}.{(stamp_ns % 1_000_000_000) // 1000:06d}"


def planes_json(scene: Scene) -> dict:
    """The scene's planes (world frame) and clutter as a JSON-ready dict."""
    areas = scene.plane_areas()
    planes = []
    for row in range(scene.n_planes):
        polys = scene.polygons_of(row)
        allv = np.concatenate(polys)
        planes.append({
            "id": int(scene.plane_ids[row]),
            "kind": scene.plane_kinds[row],
            "normal": [round(float(x), 12) for x in scene.normals[row]],
            "offset": round(float(scene.offsets[row]), 12),
            "polygons": [[[round(float(c), 9) for c in v] for v in p] for p in polys],
            "bbox_min": [round(float(c), 9) for c in allv.min(axis=0)],
            "bbox_max": [round(float(c), 9) for c in allv.max(axis=0)],
            "area_m2": round(float(areas[row]), 9),
        })
    return {
        "scene": scene.name,
        "scene_seed": scene.seed,
        "frame": "world",
        "convention": "plane n.p + d = 0 in metres; world z up, floor at z = 0; normals face the free space the "
                      "surface faces; polygons are convex, vertices in order; label 0 = no plane",
        "planes": planes,
        "clutter": {
            "cylinders_x_y_zbottom_ztop_radius": scene.cylinders.round(9).tolist(),
            "spheres_x_y_z_radius": scene.spheres.round(9).tolist(),
        },
    }


def _prepare(out: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir: {out} exists and is not a directory")
    if (out / "depth.txt").exists():
        if not overwrite:
            raise ValueError(f"out_dir: {out} already holds a sequence (depth.txt); pass overwrite=True to replace it")
        from drivers.recorder import clear_sequence

        clear_sequence(out)
    (out / "depth").mkdir(parents=True, exist_ok=True)
    (out / "labels").mkdir(parents=True, exist_ok=True)


def write_sequence(
    frames: Iterable[DepthFrame],
    scene: Scene,
    out_dir: str | os.PathLike,
    *,
    overwrite: bool = False,
    metadata: dict | None = None,
    progress: bool = False,
    total: int | None = None,
) -> WriteSummary:
    """Write ``frames`` (any iterable, consumed once; each with ``T_world_cam``) of ``scene`` into ``out_dir``.

    ``metadata`` (JSON-able) goes into ``sim.json``. With ``progress`` a tqdm bar runs (``total`` frames).
    Raises ValueError when ``out_dir`` already holds a sequence (unless ``overwrite``), a frame has no pose, or
    frames disagree on intrinsics.
    """
    from drivers.depth_png import write_depth_png, write_label_png

    t0 = time.perf_counter()
    out = Path(out_dir)
    _prepare(out, overwrite)
    depth_lines = ["# depth maps", f"# simulated: scene {scene.name}", "# timestamp filename"]
    label_lines = ["# plane labels (uint16 plane id, 0 = none)", f"# simulated: scene {scene.name}",
                   "# timestamp filename"]
    gt_lines = ["# ground truth trajectory (camera optical frame to world)", f"# simulated: scene {scene.name}",
                "# timestamp tx ty tz qx qy qz qw"]
    grav_lines = ["# gravity direction (unit, pointing down, camera frame; exact, from the simulator)",
                  f"# simulated: scene {scene.name}", "# timestamp gx gy gz"]
    n_gravity = 0
    intr = None
    valid, labelled, n_visible = [], [], []
    unrepresentable = 0
    it = frames
    if progress:
        from reloc.progress import progress_bar

        it = progress_bar(frames, total=total, unit="frame", desc=f"writing {out.name}", leave=False)
    n = 0
    last_stamp = None
    for frame in it:
        if frame.T_world_cam is None:
            raise ValueError(f"frames[{n}]: expected a frame with T_world_cam (ground truth), got none")
        if intr is None:
            intr = frame.intrinsics
        elif frame.intrinsics != intr:
            raise ValueError(f"frames[{n}]: intrinsics {frame.intrinsics} differ from the first frame's {intr}")
        if last_stamp is not None and frame.stamp_ns <= last_stamp:
            raise ValueError(f"frames[{n}]: stamp_ns {frame.stamp_ns} does not increase (previous {last_stamp})")
        last_stamp = frame.stamp_ns
        name = stamp_name(frame.stamp_ns)
        d = frame.depth_m
        ok = np.isfinite(d) & (d > 0)
        unrepresentable += int(np.count_nonzero(ok & (np.rint(np.where(ok, d, 0) * intr.depth_scale) > 65535)))
        write_depth_png(out / "depth" / f"{name}.png", d, intr.depth_scale)
        labels = frame.labels if frame.labels is not None else np.zeros(d.shape, np.int32)
        write_label_png(out / "labels" / f"{name}.png", labels)
        depth_lines.append(f"{name} depth/{name}.png")
        label_lines.append(f"{name} labels/{name}.png")
        tum = tum_from_transform(frame.T_world_cam)
        gt_lines.append(name + " " + " ".join(f"{v:.9f}" for v in tum))
        if frame.gravity_cam is not None:
            grav_lines.append(name + " " + " ".join(f"{v:.9f}" for v in frame.gravity_cam))
            n_gravity += 1
        valid.append(ok.mean())
        labelled.append((labels > 0).mean())
        n_visible.append(len(np.unique(labels[labels > 0])))
        n += 1
    if n == 0:
        raise ValueError("frames: expected at least one frame, got none")
    atomic_write_text(out / "depth.txt", "\n".join(depth_lines) + "\n")
    atomic_write_text(out / "labels.txt", "\n".join(label_lines) + "\n")
    atomic_write_text(out / "groundtruth.txt", "\n".join(gt_lines) + "\n")
    if n_gravity:
        atomic_write_text(out / "gravity.txt", "\n".join(grav_lines) + "\n")
    elif (out / "gravity.txt").exists():  # an overwritten sequence must not keep the old one's gravity
        (out / "gravity.txt").unlink()
    atomic_write_text(out / "camera.yaml", yaml.safe_dump(intr.as_dict(), sort_keys=False))
    atomic_write_text(out / "planes.json", json.dumps(planes_json(scene), indent=1) + "\n")
    summary = WriteSummary(
        out_dir=str(out), n_frames=n, width=intr.width, height=intr.height, depth_scale=float(intr.depth_scale),
        n_scene_planes=scene.n_planes, valid_fraction=float(np.mean(valid)), labelled_fraction=float(np.mean(labelled)),
        visible_planes_median=float(np.median(n_visible)), unrepresentable_pixels=unrepresentable,
        seconds=time.perf_counter() - t0,
    )
    meta = {"scene": scene.name, "scene_seed": scene.seed, **(metadata or {}), "summary": asdict(summary)}
    atomic_write_text(out / "sim.json", json.dumps(meta, indent=1, default=_json_default) + "\n")
    return summary


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
