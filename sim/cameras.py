"""Pinhole intrinsics presets for the simulated depth cameras.

| preset   | class of sensor          | size      | field of view (h x v) | depth_scale |
|----------|--------------------------|-----------|-----------------------|-------------|
| oak-d    | OAK-D stereo             | 640 x 400 | ~72 x 49 deg          | 1000 (mm)   |
| kinect   | Kinect v1 / TUM RGB-D    | 640 x 480 | ~63 x 49 deg          | 5000 (TUM)  |
| l515     | RealSense L515 (lidar)   | 1024 x 768| ~70 x 55 deg          | 4000        |
| wide-tof | wide ToF (mToF class)    | 640 x 480 | ~100 x 75 deg         | 1000 (mm)   |

Any other camera is just an :class:`~reloc.camera.Intrinsics`; ``Intrinsics.scaled`` gives smaller test images.
"""

from __future__ import annotations

import math

import numpy as np

from reloc.camera import Intrinsics

__all__ = ["PRESETS", "RATE_RANGE_HZ", "SIZE_RANGE_PX", "preset", "resolve_intrinsics"]

SIZE_RANGE_PX = (8, 4096)  # image widths and heights a simulated camera is resampled to
RATE_RANGE_HZ = (1e-3, 1e5)  # frame rates of a simulated camera (a slower one's stamps overflow int64 ns)


def _from_fov(width: int, height: int, hfov_deg: float, vfov_deg: float, depth_scale: float) -> Intrinsics:
    fx = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    fy = (height / 2) / math.tan(math.radians(vfov_deg) / 2)
    return Intrinsics(fx=round(fx, 3), fy=round(fy, 3), cx=(width - 1) / 2, cy=(height - 1) / 2,
                      width=width, height=height, depth_scale=depth_scale)


PRESETS: dict[str, Intrinsics] = {
    "oak-d": Intrinsics(fx=441.0, fy=441.0, cx=319.5, cy=199.5, width=640, height=400, depth_scale=1000.0),
    "kinect": Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480, depth_scale=5000.0),
    "l515": Intrinsics(fx=730.0, fy=730.0, cx=511.5, cy=383.5, width=1024, height=768, depth_scale=4000.0),
    "wide-tof": _from_fov(640, 480, 100.0, 75.0, 1000.0),
}


def preset(name: str) -> Intrinsics:
    """Intrinsics of the preset ``name`` (one of :data:`PRESETS`)."""
    if name not in PRESETS:
        raise ValueError(f"name: expected a camera preset among {', '.join(PRESETS)}, got {name!r}")
    return PRESETS[name]


def resolve_intrinsics(camera: "str | Intrinsics", width: int | None = None, height: int | None = None) -> Intrinsics:
    """A preset name or an Intrinsics, optionally resampled to ``width x height``."""
    if isinstance(camera, Intrinsics):
        intr = camera
    elif isinstance(camera, str):
        intr = preset(camera)
    else:
        raise ValueError(f"camera: expected a preset name or an Intrinsics, got {type(camera).__name__}")
    if width is not None or height is not None:
        if width is None or height is None:
            raise ValueError(f"width, height: give both or neither, got width={width}, height={height}")
        for name, v in (("width", width), ("height", height)):
            lo, hi = SIZE_RANGE_PX
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise ValueError(f"{name}: expected a whole number of pixels from {lo} to {hi}, got {v!r}")
        intr = intr.scaled(int(width), int(height))
    return intr
