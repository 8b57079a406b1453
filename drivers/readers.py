"""Depth sequences on disk: one reader, the format detected from the folder.

``open_sequence(path)`` returns a :class:`Sequence`; ``len()``, iteration and integer indexing give
:class:`reloc.camera.DepthFrame` (depth in metres, float32, NaN where there is no measurement), slicing gives a
shorter :class:`Sequence`. Images are read lazily, one per frame asked for; the text files are parsed and checked
when the sequence is opened, so a malformed line is reported before any work starts.

Formats (tried in this order on a folder):

- **TUM RGB-D** (``depth.txt``): ``depth.txt`` (``timestamp filename``), ``camera.yaml`` (fx, fy, cx, cy, width,
  height, depth_scale) and optionally ``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``, camera to world),
  ``odometry.txt`` (same columns, camera to odometry frame), ``accelerometer.txt`` (``timestamp ax ay az``, Kinect
  v1 axes), ``gravity.txt`` (``timestamp gx gy gz``, unit, pointing down, camera frame), ``labels/<depth name>``
  (uint16 plane ids) and ``planes.json``. This is what ``reloc sim`` and ``reloc record`` write.
  Each depth timestamp is associated with the nearest pose row; when that row is more than ``max_dt_s`` away the
  frame is kept with ``T_world_cam=None`` and counted in :attr:`Sequence.notes` (the depth is still usable for
  extraction; evaluation skips frames without a pose).
- **Microsoft 7-Scenes**: ``frame-NNNNNN.depth.png`` (millimetres, 0 and 65535 mean no measurement) with
  ``frame-NNNNNN.pose.txt`` (4x4 camera to world). Intrinsics from ``camera.yaml`` or ``camera-intrinsics.txt``
  (a 3x3 matrix or ``fx fy cx cy``) beside the frames, else the 7-Scenes default (585, 585, 320, 240).
- **Pose folder** (the ICL-NUIM clip): depth PNGs (in ``depth/`` or the folder itself, in natural order:
  ``2.png`` before ``10.png``), ``pose.txt`` with one ``tx ty tz qx qy qz qw`` line per image in that order, and
  ``camera.yaml``.
- **Single depth PNG with an OpenCV XML calibration** (the CAPE frame): the PNG path itself, or a folder holding
  one PNG and one ``.xml``; ``IR_intrinsic_params`` (the depth camera) give the intrinsics, values in millimetres.

7-Scenes and pose folders carry no timestamps: their frames are stamped ``i / rate_hz`` (30 Hz, the rate of both
datasets) and :attr:`Sequence.synthetic_stamps` says so.

Gravity from the TUM ``accelerometer.txt`` (Kinect v1). The accelerometer measures the specific force, which at rest
points UP, in axes turned 180 degrees about the optical axis from the depth camera's (x left, y up, z forward).
Checked against the motion-capture ground truth of freiburg1_xyz, whose world z is up: the best rotation between
the accelerometer and ``R_world_cam^T @ [0, 0, 1]`` over the 30 s recording is within 6 degrees of that 180 degree
turn, and the turn itself agrees with the ground truth to 5.2 degrees on average. So gravity (down, camera frame) is
``(ax, ay, -az) / |a|``, averaged over ``accel_window_s`` around each depth stamp.
"""

from __future__ import annotations

import json
import math
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Iterator, overload

import numpy as np

from drivers.depth_png import read_depth_png, read_depth_png_raw, read_label_png
from reloc.camera import DepthFrame, Intrinsics
from reloc.transforms import check_transform, transform_from_tum

__all__ = [
    "Sequence",
    "open_sequence",
    "read_intrinsics_yaml",
    "read_stamped_poses",
    "parse_stamp_ns",
    "gravity_from_kinect_accel",
    "read_noise_law",
    "noise_law_entry",
    "SEVEN_SCENES_INTRINSICS",
    "NOMINAL_RATE_HZ",
]

NOMINAL_RATE_HZ = 30.0
SEVEN_SCENES_INTRINSICS = Intrinsics(fx=585.0, fy=585.0, cx=320.0, cy=240.0, width=640, height=480, depth_scale=1000.0)
# 7-Scenes poses are printed with 7-8 significant digits; rotations farther than this from orthonormal are rejected,
# nearer ones are projected back onto SO(3).
_POSE_ORTHO_TOL = 1e-3
# Timestamps are int64 nanoseconds: seconds beyond this do not fit.
_MAX_STAMP_S = Decimal(2**63 - 1) / 1_000_000_000


@dataclass(frozen=True)
class Sequence:
    """A depth sequence on disk. Per-frame arrays have one row per frame, in stamp order.

    - ``stamps_ns`` (N,) int64, strictly increasing.
    - ``T_world_cam`` (N, 4, 4) float64, NaN rows for frames without a pose; ``has_pose`` (N,) bool.
    - ``gravity_cam`` (N, 3) float64 unit vectors pointing down in the camera frame, NaN rows where unknown.
    - ``depth_files`` and ``label_files`` (or None): one path per frame.
    - ``seqs`` (N,) int64: each frame's index in the full sequence (kept by slicing).
    - ``pose_source``: "groundtruth", "odometry" or "none"; ``notes``: what the reader chose or skipped.
    """

    path: Path
    format: str
    intrinsics: Intrinsics
    stamps_ns: np.ndarray
    depth_files: tuple[Path, ...]
    T_world_cam: np.ndarray
    gravity_cam: np.ndarray
    seqs: np.ndarray
    pose_source: str = "none"
    label_files: tuple[Path, ...] | None = None
    planes_file: Path | None = None
    invalid_raw: tuple[int, ...] = (0,)
    synthetic_stamps: bool = False
    notes: tuple[str, ...] = field(default=())

    def __len__(self) -> int:
        return len(self.depth_files)

    @overload
    def __getitem__(self, index: int) -> DepthFrame: ...

    @overload
    def __getitem__(self, index: slice) -> "Sequence": ...

    def __getitem__(self, index):
        if isinstance(index, slice):
            idx = np.arange(len(self))[index]
            return replace(
                self,
                stamps_ns=self.stamps_ns[idx],
                depth_files=tuple(self.depth_files[i] for i in idx),
                T_world_cam=self.T_world_cam[idx],
                gravity_cam=self.gravity_cam[idx],
                seqs=self.seqs[idx],
                label_files=None if self.label_files is None else tuple(self.label_files[i] for i in idx),
            )
        if isinstance(index, (int, np.integer)):
            i = int(index)
            if i < 0:
                i += len(self)
            if not 0 <= i < len(self):
                raise IndexError(f"index {index} out of range for a sequence of {len(self)} frames")
            return self._frame(i)
        raise TypeError(f"index: expected an int or a slice, got {type(index).__name__}")

    def __iter__(self) -> Iterator[DepthFrame]:
        for i in range(len(self)):
            yield self._frame(i)

    @property
    def has_pose(self) -> np.ndarray:
        """(N,) bool: frames with a pose."""
        return np.isfinite(self.T_world_cam[:, 0, 0])

    @property
    def has_gravity(self) -> np.ndarray:
        """(N,) bool: frames with a gravity direction."""
        return np.isfinite(self.gravity_cam[:, 0])

    @property
    def rate_hz(self) -> float | None:
        """Frame rate from the median stamp difference (None for fewer than two frames)."""
        if len(self) < 2:
            return None
        dt = float(np.median(np.diff(self.stamps_ns)))
        return 1e9 / dt if dt > 0 else None

    def scene_planes(self) -> list[dict] | None:
        """The ``planes.json`` of a simulated sequence (world-frame planes: id, normal, offset, ...), else None."""
        if self.planes_file is None:
            return None
        try:
            data = json.loads(self.planes_file.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{self.planes_file}: not valid JSON ({exc})") from None
        planes = data.get("planes", data) if isinstance(data, dict) else data
        if not isinstance(planes, list):
            raise ValueError(f"{self.planes_file}: expected a list of planes (or {{'planes': [...]}})")
        return planes

    def summary(self) -> str:
        """One paragraph for people: format, frame count, intrinsics, poses, gravity, notes."""
        k = self.intrinsics
        lines = [
            f"{self.path} ({self.format}): {len(self)} frames, {k.width}x{k.height}, fx={k.fx:g} fy={k.fy:g} "
            f"cx={k.cx:g} cy={k.cy:g}, depth_scale={k.depth_scale:g}",
            f"  poses ({self.pose_source}): {int(self.has_pose.sum())}/{len(self)}; "
            f"gravity: {int(self.has_gravity.sum())}/{len(self)}; labels: {'yes' if self.label_files else 'no'}",
        ]
        if len(self) > 1:
            span = (self.stamps_ns[-1] - self.stamps_ns[0]) / 1e9
            lines.append(f"  {span:.2f} s at {self.rate_hz:.1f} Hz" + (" (nominal)" if self.synthetic_stamps else ""))
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)

    def _frame(self, i: int) -> DepthFrame:
        path = self.depth_files[i]
        depth = read_depth_png(path, self.intrinsics.depth_scale, invalid_raw=self.invalid_raw)
        _check_image_shape(depth, path, self.intrinsics)
        labels = None
        if self.label_files is not None:
            labels = read_label_png(self.label_files[i])
            _check_image_shape(labels, self.label_files[i], self.intrinsics)
        T = self.T_world_cam[i]
        g = self.gravity_cam[i]
        has_T = bool(np.isfinite(T[0, 0]))
        return DepthFrame(
            depth_m=depth,
            intrinsics=self.intrinsics,
            stamp_ns=int(self.stamps_ns[i]),
            seq=int(self.seqs[i]),
            T_world_cam=T.copy() if has_T else None,
            gravity_cam=g.copy() if np.isfinite(g[0]) else None,
            pose_source=self.pose_source if has_T else "none",
            labels=labels,
        )


def open_sequence(
    path: str | os.PathLike,
    *,
    max_dt_s: float = 0.02,
    poses: str = "auto",
    accel_window_s: float = 0.05,
) -> Sequence:
    """Open a depth sequence, detecting its format from the folder (see the module docstring).

    - ``max_dt_s``: largest gap between a depth stamp and its associated pose / gravity row (TUM layout).
    - ``poses``: "auto" (ground truth when present, else odometry), "groundtruth", "odometry" or "none".
    - ``accel_window_s``: accelerometer samples within this many seconds of a depth stamp are averaged.

    Raises FileNotFoundError for a missing folder or file and ValueError (naming the file and line) for malformed
    content.
    """
    if not (isinstance(max_dt_s, (int, float)) and max_dt_s > 0):
        raise ValueError(f"max_dt_s: expected a positive number of seconds, got {max_dt_s!r}")
    if poses not in ("auto", "groundtruth", "odometry", "none"):
        raise ValueError(f"poses: expected 'auto', 'groundtruth', 'odometry' or 'none', got {poses!r}")
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: sequence not found")
    if p.is_file():
        if p.suffix.lower() in (".ply", ".npy"):
            raise ValueError(f"{p}: a point cloud, not a depth sequence (read it with drivers.pointcloud.read_point_cloud)")
        if p.suffix.lower() != ".png":
            raise ValueError(f"{p}: expected a sequence folder or a depth .png, got a {p.suffix or 'suffix-less'} file")
        return _open_single_png(p)
    if (p / "depth.txt").is_file():
        return _open_tum(p, max_dt_s=max_dt_s, poses=poses, accel_window_s=accel_window_s)
    if any(p.glob("frame-*.depth.png")):
        return _open_seven_scenes(p, poses=poses)
    if (p / "pose.txt").is_file():
        return _open_pose_folder(p, poses=poses)
    pngs = sorted(p.glob("*.png"))
    if len(pngs) == 1:
        return _open_single_png(pngs[0])
    raise ValueError(
        f"{p}: unknown sequence layout; expected depth.txt (TUM RGB-D), frame-NNNNNN.depth.png (7-Scenes), "
        f"pose.txt with depth PNGs, or a single depth PNG with camera.yaml or an OpenCV .xml calibration"
    )


# --------------------------------------------------------------------------------------------------- formats


def _open_tum(root: Path, *, max_dt_s: float, poses: str, accel_window_s: float) -> Sequence:
    intrinsics = read_intrinsics_yaml(root / "camera.yaml")
    stamps, files = _read_depth_list(root / "depth.txt", root)

    n = len(files)
    T = np.full((n, 4, 4), np.nan)
    notes: list[str] = []
    pose_source = "none"
    wanted = {"auto": ("groundtruth", "odometry"), "groundtruth": ("groundtruth",), "odometry": ("odometry",)}
    for source in wanted.get(poses, ()):
        pose_file = root / f"{source}.txt"
        if not pose_file.is_file():
            if poses != "auto":
                raise FileNotFoundError(f"{pose_file}: {source} poses asked for but the file does not exist")
            continue
        pose_stamps, pose_T = read_stamped_poses(pose_file)
        idx, dt = _nearest(stamps, pose_stamps)
        ok = dt <= max_dt_s * 1e9
        T[ok] = pose_T[idx[ok]]
        pose_source = source
        if not ok.all():
            notes.append(
                f"{int((~ok).sum())} of {n} depth frames have no {source} row within {max_dt_s * 1e3:g} ms "
                f"(kept without a pose; first: {files[int(np.argmin(ok))].name})"
            )
        break

    gravity = np.full((n, 3), np.nan)
    if (root / "gravity.txt").is_file():
        g_stamps, g_vals = _read_stamped_vectors(root / "gravity.txt", "timestamp gx gy gz")
        idx, dt = _nearest(stamps, g_stamps)
        ok = dt <= max_dt_s * 1e9
        gravity[ok] = _unit_rows(g_vals[idx[ok]], root / "gravity.txt")
    elif (root / "accelerometer.txt").is_file():
        a_stamps, a_vals = _read_stamped_vectors(root / "accelerometer.txt", "timestamp ax ay az")
        gravity = gravity_from_kinect_accel(stamps, a_stamps, a_vals, window_s=accel_window_s)
    if (root / "gravity.txt").is_file() or (root / "accelerometer.txt").is_file():
        missing = int((~np.isfinite(gravity[:, 0])).sum())
        if missing:
            notes.append(f"{missing} of {n} depth frames have no IMU sample nearby (kept without gravity)")

    label_files = None
    if (root / "labels").is_dir():
        label_files = tuple(root / "labels" / f.name for f in files)
        for f in label_files:
            if not f.is_file():
                raise FileNotFoundError(f"{f}: label image missing (labels/ must hold one PNG per depth image)")
    planes_file = root / "planes.json" if (root / "planes.json").is_file() else None
    return Sequence(
        path=root, format="tum", intrinsics=intrinsics, stamps_ns=stamps, depth_files=files, T_world_cam=T,
        gravity_cam=gravity, seqs=np.arange(n, dtype=np.int64), pose_source=pose_source, label_files=label_files,
        planes_file=planes_file, notes=tuple(notes),
    )


def _open_seven_scenes(root: Path, *, poses: str) -> Sequence:
    files = tuple(sorted(root.glob("frame-*.depth.png"), key=lambda f: _natural_key(f.name)))
    intrinsics, note = _seven_scenes_intrinsics(root, files[0])
    n = len(files)
    T = np.full((n, 4, 4), np.nan)
    pose_files = [f.with_name(f.name[: -len(".depth.png")] + ".pose.txt") for f in files]
    have = [pf.is_file() for pf in pose_files]
    pose_source = "none"
    if poses in ("auto", "groundtruth") and any(have):
        for i, pf in enumerate(pose_files):
            if not have[i]:
                raise FileNotFoundError(f"{pf}: pose file missing for {files[i].name} (other frames have one)")
            T[i] = _read_matrix_pose(pf)
        pose_source = "groundtruth"
    elif poses == "groundtruth":
        raise FileNotFoundError(f"{root}: groundtruth poses asked for but there are no frame-*.pose.txt files")
    elif poses == "odometry":
        raise ValueError(f"{root}: poses='odometry' asked for but 7-Scenes folders hold only ground-truth poses")
    return Sequence(
        path=root, format="7scenes", intrinsics=intrinsics, stamps_ns=_nominal_stamps(n), depth_files=files,
        T_world_cam=T, gravity_cam=np.full((n, 3), np.nan), seqs=np.arange(n, dtype=np.int64),
        pose_source=pose_source, invalid_raw=(0, 65535), synthetic_stamps=True, notes=(note,) if note else (),
    )


def _open_pose_folder(root: Path, *, poses: str) -> Sequence:
    intrinsics = read_intrinsics_yaml(root / "camera.yaml")
    image_dir = root / "depth" if (root / "depth").is_dir() else root
    files = tuple(sorted(image_dir.glob("*.png"), key=lambda f: _natural_key(f.name)))
    if not files:
        raise FileNotFoundError(f"{image_dir}: no depth PNGs beside {root / 'pose.txt'}")
    n = len(files)
    T = np.full((n, 4, 4), np.nan)
    pose_source = "none"
    if poses in ("auto", "groundtruth"):
        rows = _read_numeric_rows(root / "pose.txt", 7, "tx ty tz qx qy qz qw")
        if len(rows) != n:
            raise ValueError(
                f"{root / 'pose.txt'}: {len(rows)} pose lines for {n} depth images in {image_dir} "
                f"(expected one line per image, in natural file order)"
            )
        for i, (lineno, values) in enumerate(rows):
            T[i] = _tum_pose(values, root / "pose.txt", lineno)
        pose_source = "groundtruth"
    elif poses == "odometry":
        raise ValueError(f"{root}: poses='odometry' asked for but a pose folder holds only ground truth (pose.txt)")
    return Sequence(
        path=root, format="pose_folder", intrinsics=intrinsics, stamps_ns=_nominal_stamps(n), depth_files=files,
        T_world_cam=T, gravity_cam=np.full((n, 3), np.nan), seqs=np.arange(n, dtype=np.int64),
        pose_source=pose_source, synthetic_stamps=True,
    )


def _open_single_png(png: Path) -> Sequence:
    raw = read_depth_png_raw(png)
    h, w = raw.shape
    yaml_file = png.parent / "camera.yaml"
    xmls = sorted(png.parent.glob("*.xml"))
    if yaml_file.is_file():
        intrinsics = read_intrinsics_yaml(yaml_file)
    elif len(xmls) == 1:
        intrinsics = read_opencv_xml_intrinsics(xmls[0], width=w, height=h)
    else:
        raise FileNotFoundError(
            f"{png}: no calibration beside it; expected camera.yaml or exactly one OpenCV .xml "
            f"(found {len(xmls)} .xml files)"
        )
    _check_image_shape(raw, png, intrinsics)
    return Sequence(
        path=png, format="single_png", intrinsics=intrinsics, stamps_ns=np.zeros(1, dtype=np.int64),
        depth_files=(png,), T_world_cam=np.full((1, 4, 4), np.nan), gravity_cam=np.full((1, 3), np.nan),
        seqs=np.zeros(1, dtype=np.int64), synthetic_stamps=True,
    )


# --------------------------------------------------------------------------------------------------- files


_NOISE_LAW_FILES = ("recording.json", "sim.json")
_NOISE_MODELS = ("kinect", "tof", "stereo", "constant")


def noise_law_entry(law: "tuple[str, float] | None") -> "dict | None":
    """The ``noise_law`` entry of ``recording.json`` / ``sim.json`` for ``(noise_model, noise_coeff)``."""
    return None if law is None else {"model": str(law[0]), "coeff": float(law[1])}


def read_noise_law(path: "str | os.PathLike") -> "tuple[str, float] | None":
    """``(noise_model, noise_coeff)`` stored by ``reloc record`` (``recording.json``) or ``reloc sim`` (``sim.json``)
    in the sequence folder ``path`` (or the folder of a file), or None when neither holds one. A malformed entry
    raises ValueError naming the file."""
    root = Path(path)
    root = root if root.is_dir() else root.parent
    for name in _NOISE_LAW_FILES:
        f = root / name
        if not f.is_file():
            continue
        try:
            meta = json.loads(f.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f"{f}: not readable JSON ({exc})") from None
        entry = meta.get("noise_law") if isinstance(meta, dict) else None
        if entry is None:
            continue
        model = entry.get("model") if isinstance(entry, dict) else None
        coeff = entry.get("coeff") if isinstance(entry, dict) else None
        if model not in _NOISE_MODELS or isinstance(coeff, bool) or not isinstance(coeff, (int, float)) or not (
                math.isfinite(coeff) and coeff > 0):
            raise ValueError(f"{f}: noise_law {entry!r}, expected {{\"model\": one of {', '.join(_NOISE_MODELS)}, "
                             "\"coeff\": a positive number}")
        return model, float(coeff)
    return None


def read_intrinsics_yaml(path: Path) -> Intrinsics:
    """Intrinsics from a ``camera.yaml`` (fx, fy, cx, cy, width, height, depth_scale)."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: camera intrinsics file not found (fx, fy, cx, cy, width, height, depth_scale)")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not valid YAML ({exc})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a UTF-8 text file") from None
    except RecursionError:
        raise ValueError(f"{path}: YAML nested too deeply") from None
    intrinsics = Intrinsics.from_dict(data, source=str(path))
    if "depth_scale" not in data:
        # No default: TUM RGB-D stores 5000 per metre, most cameras 1000, and a guess puts every depth 5 times off.
        raise ValueError(f"{path}: missing key depth_scale (the depth images' integers per metre: 5000 for TUM RGB-D, "
                         f"1000 for millimetres); expected fx, fy, cx, cy, width, height, depth_scale")
    return intrinsics


def read_opencv_xml_intrinsics(
    path: Path, *, width: int, height: int, depth_scale: float = 1000.0, matrix: str = "IR_intrinsic_params"
) -> Intrinsics:
    """Intrinsics from the 3x3 ``matrix`` (default ``IR_intrinsic_params``, the depth camera) of an OpenCV XML file."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not valid XML ({exc})") from None
    node = root.find(matrix)
    if node is None:
        names = [child.tag for child in root]
        raise ValueError(f"{path}: no <{matrix}> matrix (the depth camera's intrinsics); found {names}")
    try:
        rows, cols = int(node.findtext("rows")), int(node.findtext("cols"))
        values = np.array([float(v) for v in (node.findtext("data") or "").split()])
    except (TypeError, ValueError):
        raise ValueError(f"{path}: <{matrix}> is not an OpenCV matrix with rows, cols and data") from None
    if (rows, cols) != (3, 3) or values.size != 9 or not np.all(np.isfinite(values)):
        raise ValueError(f"{path}: <{matrix}> expected 9 finite values of a 3x3 matrix, got {rows}x{cols}: {values}")
    K = values.reshape(3, 3)
    return Intrinsics(
        fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]), width=int(width),
        height=int(height), depth_scale=depth_scale,
    )


def parse_stamp_ns(text: str, where: str = "timestamp") -> int:
    """Exact integer nanoseconds from a decimal seconds string (``1305031102.160407`` -> 1305031102160407000)."""
    try:
        value = Decimal(text)
    except InvalidOperation:
        raise ValueError(f"{where}: expected a timestamp in seconds, got {text!r}") from None
    if not value.is_finite():
        raise ValueError(f"{where}: expected a finite timestamp, got {text!r}")
    if value.copy_abs() >= _MAX_STAMP_S:  # (before int(): "1e999999999" would build a billion-digit integer)
        raise ValueError(f"{where}: expected a timestamp within +-{_MAX_STAMP_S} s (int64 nanoseconds), got {text!r}")
    return int((value * 1_000_000_000).to_integral_value())


def read_stamped_poses(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``timestamp tx ty tz qx qy qz qw`` lines -> (stamps_ns (M,) int64 sorted, T (M, 4, 4))."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: pose file not found")
    stamps, poses = [], []
    for lineno, fields in _text_lines(path):
        where = f"{path}:{lineno}"
        if len(fields) != 8:
            raise ValueError(f"{where}: expected 8 columns 'timestamp tx ty tz qx qy qz qw', got {len(fields)}")
        stamps.append(parse_stamp_ns(fields[0], where))
        poses.append(_tum_pose(_floats(fields[1:], where), path, lineno))
    if not stamps:
        raise ValueError(f"{path}: no pose lines (expected 'timestamp tx ty tz qx qy qz qw')")
    stamps_arr = np.array(stamps, dtype=np.int64)
    order = np.argsort(stamps_arr, kind="stable")
    return stamps_arr[order], np.array(poses)[order]


def gravity_from_kinect_accel(
    stamps_ns: np.ndarray, accel_stamps_ns: np.ndarray, accel: np.ndarray, *, window_s: float = 0.05
) -> np.ndarray:
    """Gravity (unit, down, depth camera frame) per stamp from TUM/Kinect v1 accelerometer samples.

    The mean specific force over ``stamps +- window_s`` is turned from the accelerometer axes (x left, y up,
    z forward; it points up at rest) into gravity in the optical frame: ``(ax, ay, -az) / |a|``. Rows without a
    sample in the window are NaN. Returns (N, 3) float64.
    """
    order = np.argsort(accel_stamps_ns, kind="stable")
    a_t = np.asarray(accel_stamps_ns, dtype=np.int64)[order]
    a = np.asarray(accel, dtype=np.float64)[order]
    csum = np.vstack([np.zeros((1, 3)), np.cumsum(a, axis=0)])
    half = int(window_s * 1e9)
    lo = np.searchsorted(a_t, np.asarray(stamps_ns) - half, side="left")
    hi = np.searchsorted(a_t, np.asarray(stamps_ns) + half, side="right")
    out = np.full((len(lo), 3), np.nan)
    has = hi > lo
    mean = (csum[hi[has]] - csum[lo[has]]) / (hi[has] - lo[has])[:, None]
    down = mean * np.array([1.0, 1.0, -1.0])
    norm = np.linalg.norm(down, axis=1, keepdims=True)
    ok = norm[:, 0] > 1e-6
    res = np.full_like(down, np.nan)
    res[ok] = down[ok] / norm[ok]
    out[has] = res
    return out


def _read_depth_list(path: Path, root: Path) -> tuple[np.ndarray, tuple[Path, ...]]:
    stamps, files = [], []
    for lineno, fields in _text_lines(path):
        where = f"{path}:{lineno}"
        if len(fields) != 2:
            raise ValueError(f"{where}: expected 'timestamp filename', got {' '.join(fields)!r}")
        stamp = parse_stamp_ns(fields[0], where)
        if stamps and stamp <= stamps[-1]:
            raise ValueError(f"{where}: timestamps must increase, got {fields[0]} after {stamps[-1] / 1e9:.6f}")
        f = root / fields[1]
        if not f.is_file():
            raise FileNotFoundError(f"{f}: depth image listed at {where} not found")
        stamps.append(stamp)
        files.append(f)
    if not files:
        raise ValueError(f"{path}: no depth frames listed (expected 'timestamp filename' lines)")
    return np.array(stamps, dtype=np.int64), tuple(files)


def _read_stamped_vectors(path: Path, columns: str) -> tuple[np.ndarray, np.ndarray]:
    stamps, values = [], []
    for lineno, fields in _text_lines(path):
        where = f"{path}:{lineno}"
        if len(fields) != 4:
            raise ValueError(f"{where}: expected 4 columns '{columns}', got {len(fields)}")
        stamps.append(parse_stamp_ns(fields[0], where))
        values.append(_floats(fields[1:], where))
    if not stamps:
        raise ValueError(f"{path}: no data lines (expected '{columns}')")
    return np.array(stamps, dtype=np.int64), np.array(values)


def _read_numeric_rows(path: Path, ncols: int, columns: str) -> list[tuple[int, np.ndarray]]:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found (expected '{columns}' lines)")
    rows = []
    for lineno, fields in _text_lines(path):
        where = f"{path}:{lineno}"
        if len(fields) != ncols:
            raise ValueError(f"{where}: expected {ncols} numbers '{columns}', got {len(fields)}")
        rows.append((lineno, _floats(fields, where)))
    return rows


def _read_matrix_pose(path: Path) -> np.ndarray:
    """A 4x4 pose written as 4 lines of 4 numbers (7-Scenes)."""
    rows = _read_numeric_rows(path, 4, "4 numbers per row of a 4x4 matrix")
    if len(rows) != 4:
        raise ValueError(f"{path}: expected a 4x4 matrix (4 lines of 4 numbers), got {len(rows)} lines")
    return _rigid(np.array([r for _, r in rows]), f"{path}")


def _tum_pose(values: np.ndarray, path: Path, lineno: int) -> np.ndarray:
    where = f"{path}:{lineno}"
    q_norm = float(np.linalg.norm(values[3:]))
    if abs(q_norm - 1.0) > 1e-2:
        raise ValueError(f"{where}: expected a unit quaternion 'qx qy qz qw', got norm {q_norm:.4f}")
    return transform_from_tum(values)


def _rigid(M: np.ndarray, where: str) -> np.ndarray:
    """Project a nearly rigid printed matrix onto SE(3); reject one that is not close."""
    R = M[:3, :3]
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > _POSE_ORTHO_TOL or np.linalg.det(R) <= 0 or not np.allclose(M[3], (0, 0, 0, 1), atol=1e-6):
        raise ValueError(
            f"{where}: expected a rigid 4x4 transform (orthonormal rotation, last row 0 0 0 1), "
            f"got max |R R^T - I| = {err:.3g}, last row {M[3].tolist()}"
        )
    U, _, Vt = np.linalg.svd(R)
    out = M.copy()
    out[:3, :3] = U @ Vt
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return check_transform(out, where)


def _seven_scenes_intrinsics(root: Path, first: Path) -> tuple[Intrinsics, str]:
    if (root / "camera.yaml").is_file():
        return read_intrinsics_yaml(root / "camera.yaml"), ""
    h, w = read_depth_png_raw(first).shape
    txt = root / "camera-intrinsics.txt"
    if txt.is_file():
        rows = [(ln, f) for ln, f in _text_lines(txt)]
        values = np.array([v for ln, f in rows for v in _floats(f, f"{txt}:{ln}")])
        if values.size == 9:
            K = values.reshape(3, 3)
            fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        elif values.size == 4:
            fx, fy, cx, cy = values
        else:
            raise ValueError(f"{txt}: expected a 3x3 camera matrix or 'fx fy cx cy', got {values.size} numbers")
        try:
            return Intrinsics(float(fx), float(fy), float(cx), float(cy), w, h, depth_scale=1000.0), ""
        except ValueError as exc:
            raise ValueError(f"{txt}: {exc}") from None
    if (w, h) != (640, 480):
        raise ValueError(
            f"{first}: image is {w}x{h} and there is no camera.yaml or camera-intrinsics.txt; the 7-Scenes default "
            f"intrinsics are for 640x480"
        )
    return SEVEN_SCENES_INTRINSICS, "no camera.yaml or camera-intrinsics.txt: 7-Scenes default intrinsics"


# --------------------------------------------------------------------------------------------------- helpers


def _text_lines(path: Path) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of the non-blank, non-comment lines of a text file."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: not found") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a UTF-8 text file") from None
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            yield lineno, line.replace(",", " ").split()


def _floats(fields: list[str], where: str) -> np.ndarray:
    try:
        values = np.array([float(f) for f in fields])
    except ValueError:
        raise ValueError(f"{where}: expected numbers, got {' '.join(fields)!r}") from None
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{where}: expected finite numbers, got {' '.join(fields)!r}")
    return values


def _unit_rows(v: np.ndarray, path: Path) -> np.ndarray:
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    if np.any(norm < 1e-9):
        raise ValueError(f"{path}: expected non-zero gravity vectors")
    return v / norm


def _nearest(stamps: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the nearest ``ref`` stamp (sorted) for each stamp, and the absolute gap in ns."""
    pos = np.clip(np.searchsorted(ref, stamps), 1, max(len(ref) - 1, 1))
    left = np.clip(pos - 1, 0, len(ref) - 1)
    right = np.clip(pos, 0, len(ref) - 1)
    pick_right = np.abs(ref[right] - stamps) < np.abs(stamps - ref[left])
    idx = np.where(pick_right, right, left)
    return idx, np.abs(ref[idx] - stamps)


def _nominal_stamps(n: int, rate_hz: float = NOMINAL_RATE_HZ) -> np.ndarray:
    return np.round(np.arange(n) * (1e9 / rate_hz)).astype(np.int64)


def _natural_key(name: str) -> list:
    return [int(tok) if tok.isdigit() else tok for tok in re.split(r"(\d+)", name)]


def _check_image_shape(img: np.ndarray, path: Path, intrinsics: Intrinsics) -> None:
    if img.shape != intrinsics.shape:
        raise ValueError(
            f"{path}: image is {img.shape[1]}x{img.shape[0]}, expected {intrinsics.width}x{intrinsics.height} "
            f"(width x height of the intrinsics)"
        )
