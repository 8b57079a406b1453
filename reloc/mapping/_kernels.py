"""Numba kernels of map building: carving the free space a depth frame saw (arrays in, arrays out)."""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup

_OFF = 1 << 20
_MASK = (1 << 21) - 1


@njit
def carve_free_space(depth, fx, fy, cx, cy, R, t, stride, voxel, margin, max_range, out):
    """Keys of the voxels (edge ``voxel``) that the rays of ``depth`` crossed before their surface.

    Every ``stride``-th pixel with a valid depth ``z`` (finite, 0 < z <= ``max_range``) casts a ray from the camera
    to its point; the ray is sampled every ``voxel / 2`` up to ``margin`` before the point, and each sample's voxel
    (in the frame of ``T = (R, t)``, the map) is written to ``out`` (consecutive repeats skipped). Returns the number
    of keys written (``out`` must be large enough: (H / stride) * (W / stride) * (max_range / (voxel / 2) + 1)).
    """
    H, W = depth.shape
    n = 0
    step = 0.5 * voxel
    cap = out.shape[0]
    for v in range(0, H, stride):
        for u in range(0, W, stride):
            z = depth[v, u]
            if not (z > 0.0) or z > max_range or not math.isfinite(z):
                continue
            x = (u - cx) / fx * z
            y = (v - cy) / fy * z
            length = math.sqrt(x * x + y * y + z * z)
            usable = length - margin
            if usable <= 0.0:
                continue
            dx, dy, dz = x / length, y / length, z / length
            last = np.int64(-1)
            s = 0.0
            while s < usable:
                px = dx * s
                py = dy * s
                pz = dz * s
                mx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
                my = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
                mz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
                ix = (int(math.floor(mx / voxel)) + _OFF) & _MASK
                iy = (int(math.floor(my / voxel)) + _OFF) & _MASK
                iz = (int(math.floor(mz / voxel)) + _OFF) & _MASK
                key = (np.int64(ix) << 42) | (np.int64(iy) << 21) | np.int64(iz)
                if key != last and n < cap:
                    out[n] = key
                    n += 1
                    last = key
                s += step
    return n


@register_warmup
def _warmup() -> None:
    depth = np.full((4, 4), 2.0, np.float32)
    out = np.empty(1000, np.int64)
    carve_free_space(depth, 2.0, 2.0, 2.0, 2.0, np.eye(3), np.zeros(3), 1, 0.2, 0.3, 5.0, out)
