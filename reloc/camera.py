"""Pinhole intrinsics and the depth frame that every source produces and every stage consumes.

Camera optical frame: x right, y down, z forward (OpenCV / depthai). A pixel ``(u, v)`` with depth ``z`` back-projects
to ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy``. ICL-NUIM publishes a negative ``fy`` (its image y axis is
flipped); that is supported as given, so its points come out in the dataset's own convention.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from reloc.transforms import check_transform

__all__ = ["Intrinsics", "DepthFrame", "POSE_SOURCES", "gravity_from_camera_y"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a depth image.

    ``depth_scale`` converts stored integers to metres: ``depth_m = raw / depth_scale`` (5000 for TUM, 1000 for
    millimetre sensors).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    depth_scale: float = 1000.0

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy", "depth_scale"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)) or \
                    not np.isfinite(v):
                raise ValueError(f"Intrinsics.{name}: expected a finite number, got {v!r}")
            object.__setattr__(self, name, float(v))  # numpy scalars (a float32 calibration) become Python floats
        if abs(self.fx) < 1e-9 or abs(self.fy) < 1e-9:
            raise ValueError(f"Intrinsics: expected non-zero focal lengths, got fx={self.fx}, fy={self.fy}")
        if self.fx < 0:
            raise ValueError(f"Intrinsics.fx: expected > 0, got {self.fx} (only fy may be negative, as in ICL-NUIM)")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise ValueError(f"Intrinsics.{name}: expected a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.depth_scale <= 0:
            raise ValueError(f"Intrinsics.depth_scale: expected > 0, got {self.depth_scale}")

    @property
    def K(self) -> np.ndarray:
        """The 3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)``."""
        return (self.height, self.width)

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """Intrinsics of the same camera resampled to ``width x height`` (pixel-centre convention)."""
        sx = width / self.width
        sy = height / self.height
        return replace(
            self,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=int(width),
            height=int(height),
        )

    def as_dict(self) -> dict:
        return {
            "fx": float(self.fx), "fy": float(self.fy), "cx": float(self.cx), "cy": float(self.cy),
            "width": int(self.width), "height": int(self.height), "depth_scale": float(self.depth_scale),
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "intrinsics") -> "Intrinsics":
        """Build from a mapping with keys fx, fy, cx, cy, width, height and optional depth_scale."""
        if not isinstance(d, dict):
            raise ValueError(f"{source}: expected a mapping with fx, fy, cx, cy, width, height, got {type(d).__name__}")
        missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in d]
        if missing:
            raise ValueError(f"{source}: missing keys {missing}; expected fx, fy, cx, cy, width, height[, depth_scale]")
        for key in ("fx", "fy", "cx", "cy", "width", "height", "depth_scale"):
            v = d.get(key)
            # Never silently corrected: a yes/no is not a number, and an image size is a whole number of pixels.
            if isinstance(v, bool) or (key in ("width", "height") and isinstance(v, float) and not v.is_integer()):
                raise ValueError(f"{source}: {key}: expected a {'whole ' if key in ('width', 'height') else ''}"
                                 f"number, got {v!r}")
        try:
            return cls(
                fx=float(d["fx"]), fy=float(d["fy"]), cx=float(d["cx"]), cy=float(d["cy"]),
                width=int(d["width"]), height=int(d["height"]),
                depth_scale=float(d.get("depth_scale", 1000.0)),
            )
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from None


def gravity_from_camera_y(intrinsics: Intrinsics | None = None) -> np.ndarray:
    """Gravity direction (unit, pointing down) for a level camera: +y of the optical frame, or -y for
    ``intrinsics`` with a negative ``fy`` (ICL-NUIM: their points come out with y up)."""
    return np.array([0.0, -1.0 if intrinsics is not None and intrinsics.fy < 0 else 1.0, 0.0])


#: What a frame's ``T_world_cam`` is: exact (a dataset's or the simulator's ground truth), odometry, or absent.
POSE_SOURCES = ("groundtruth", "odometry", "none")


@dataclass(frozen=True)
class DepthFrame:
    """One depth image with what is known about it.

    - ``depth_m``: (H, W) float32 metres; NaN or 0 mean no measurement.
    - ``stamp_ns``: int64 nanoseconds (sensor or host clock, as the source says).
    - ``seq``: sequence number from the source, increasing.
    - ``T_world_cam``: optional 4x4 pose (ground truth or odometry; ``pose_source`` says which).
    - ``gravity_cam``: optional unit vector (3,) of gravity (pointing down) in the camera frame.
    - ``pose_source``: one of :data:`POSE_SOURCES`: "groundtruth" (a dataset's or the simulator's exact pose, the
      name of the TUM file it is read from and written to), "odometry" or "none".
    """

    depth_m: np.ndarray
    intrinsics: Intrinsics
    stamp_ns: int
    seq: int = 0
    T_world_cam: np.ndarray | None = None
    gravity_cam: np.ndarray | None = None
    pose_source: str = "none"
    labels: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        depth = self.depth_m
        if not isinstance(depth, np.ndarray) or depth.ndim != 2:
            raise ValueError(f"DepthFrame.depth_m: expected a 2-D array, got {getattr(depth, 'shape', type(depth))}")
        if depth.shape != self.intrinsics.shape:
            raise ValueError(
                f"DepthFrame.depth_m: shape {depth.shape} does not match intrinsics (height, width) = "
                f"{self.intrinsics.shape}"
            )
        if depth.dtype.kind not in "uif":  # no booleans, text, dates, records or objects read as depths
            raise ValueError(f"DepthFrame.depth_m: expected numbers (metres), got dtype {depth.dtype}")
        if depth.dtype != np.float32:
            object.__setattr__(self, "depth_m", depth.astype(np.float32))
        if (isinstance(self.stamp_ns, bool) or not isinstance(self.stamp_ns, (int, np.integer))
                or not -(2**63) <= int(self.stamp_ns) < 2**63):
            raise ValueError(f"DepthFrame.stamp_ns: expected an integer nanosecond timestamp (int64), got {self.stamp_ns!r}")
        object.__setattr__(self, "stamp_ns", int(self.stamp_ns))
        if self.T_world_cam is not None:
            object.__setattr__(self, "T_world_cam", check_transform(self.T_world_cam, "DepthFrame.T_world_cam"))
        if self.gravity_cam is not None:
            g = np.asarray(self.gravity_cam, dtype=np.float64).reshape(-1)
            norm = np.linalg.norm(g) if g.shape == (3,) else 0.0
            if g.shape != (3,) or not np.isfinite(norm) or norm < 1e-9:
                raise ValueError(f"DepthFrame.gravity_cam: expected a non-zero 3-vector, got {g.tolist()}")
            object.__setattr__(self, "gravity_cam", g / norm)
        if self.pose_source not in POSE_SOURCES:
            raise ValueError(f"DepthFrame.pose_source: expected one of {', '.join(POSE_SOURCES)}, "
                             f"got {self.pose_source!r}")
        if self.labels is not None and self.labels.shape != depth.shape:
            raise ValueError(f"DepthFrame.labels: expected shape {depth.shape}, got {self.labels.shape}")

    @property
    def valid_mask(self) -> np.ndarray:
        """Pixels with a usable measurement (finite and > 0)."""
        d = self.depth_m
        return np.isfinite(d) & (d > 0)
