"""Stage 1: a depth image becomes camera-frame points, each with the pixel it came from."""

from __future__ import annotations

import math

import numpy as np

from reloc.camera import Intrinsics
from reloc.extraction import _kernels_voxel as kv
from reloc.extraction._workspace import Workspace, fresh
from reloc.extraction.params import noise_law_code
from reloc.extraction.voxelize import MAX_FRUSTUM_CELLS, frustum_cells

__all__ = ["depth_to_points", "depth_to_key_image", "drop_flying_pixels"]

# A step of less than this fraction of the depth is never taken for a jump between surfaces.
FLYING_MIN_REL = 0.03


def depth_to_points(
    depth_m: np.ndarray,
    intrinsics: Intrinsics,
    *,
    min_depth_m: float = 0.3,
    max_depth_m: float = 8.0,
    pixel_stride: int = 1,
    workspace: Workspace | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Back-project the valid pixels of a depth image.

    Args:
        depth_m: (H, W) depth in metres (float32 preferred); 0, NaN, inf, negative values and depths outside
            ``[min_depth_m, max_depth_m]`` are dropped, never propagated.
        intrinsics: pinhole intrinsics of the image (a negative ``fy``, as in ICL-NUIM, is used as given).
        pixel_stride: use every n-th pixel in both directions.
        workspace: reuse buffers across calls (the returned arrays are then views, valid until the next call).

    Returns:
        ``(points (M, 3) float32 in the camera frame, pixels (M,) int32 flat index v * W + u)``, row-major order.
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2 or depth.shape != intrinsics.shape:
        raise ValueError(f"depth_m: expected shape {intrinsics.shape} (from the intrinsics), got {depth.shape}")
    if depth.dtype != np.float32:
        depth = depth.astype(np.float32)
    depth = np.ascontiguousarray(depth)
    if not isinstance(pixel_stride, (int, np.integer)) or pixel_stride < 1:
        raise ValueError(f"pixel_stride: expected an integer >= 1, got {pixel_stride!r}")
    if not (0 <= min_depth_m < max_depth_m):
        raise ValueError(f"min_depth_m, max_depth_m: expected 0 <= min < max, got {min_depth_m}, {max_depth_m}")
    h, w = depth.shape
    cap = ((h + pixel_stride - 1) // pixel_stride) * ((w + pixel_stride - 1) // pixel_stride)
    ws = fresh(workspace)
    pts = ws.get("bp_points", (cap, 3), np.float32)
    pix = ws.get("bp_pixels", cap, np.int32)
    m = kv.backproject(depth, float(intrinsics.fx), float(intrinsics.fy), float(intrinsics.cx),
                       float(intrinsics.cy), int(pixel_stride), float(min_depth_m), float(max_depth_m), pts, pix)
    return pts[:m], pix[:m]


def depth_to_key_image(
    depth_m: np.ndarray,
    intrinsics: Intrinsics,
    box: np.ndarray,
    *,
    voxel_size_m: float,
    min_depth_m: float = 0.3,
    max_depth_m: float = 8.0,
    pixel_stride: int = 1,
    workspace: Workspace | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]:
    """The first half of image-order voxelization: the dense voxel key (in ``box``, from ``voxelize.frustum_box``)
    of every ``pixel_stride``-th pixel, -1 where the depth is invalid (as :func:`depth_to_points`), and the points
    per cell, without storing any point (``voxelize.voxelize_key_image`` makes them straight in voxel order).

    Returns ``(depth (H, W) float32 contiguous, pixel_key (ceil(H/s) * ceil(W/s),) int32, cellcount (nx*ny*nz,)
    int32, number of valid pixels, runs)``: ``runs`` (R + 1,) int32 the index in ``pixel_key`` where each run of
    equal keys starts (a row of pixels always starts one), then the end.
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2 or depth.shape != intrinsics.shape:
        raise ValueError(f"depth_m: expected shape {intrinsics.shape} (from the intrinsics), got {depth.shape}")
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    if not isinstance(pixel_stride, (int, np.integer)) or pixel_stride < 1:
        raise ValueError(f"pixel_stride: expected an integer >= 1, got {pixel_stride!r}")
    if not (0 <= min_depth_m < max_depth_m):
        raise ValueError(f"min_depth_m, max_depth_m: expected 0 <= min < max, got {min_depth_m}, {max_depth_m}")
    h, w = depth.shape
    cap = ((h + pixel_stride - 1) // pixel_stride) * ((w + pixel_stride - 1) // pixel_stride)
    ws = fresh(workspace)
    pixel_key = ws.get("bp_pixel_key", cap, np.int32)
    cells = frustum_cells(box)
    if cells > MAX_FRUSTUM_CELLS:
        raise ValueError(f"box: {cells} frustum cells, expected at most {MAX_FRUSTUM_CELLS} (voxelize the points "
                         f"instead, as extract_planes does)")
    cellcount = ws.get("vx_cellmap", cells, np.int32)
    runs = ws.get("bp_runs", cap + 1, np.int32)
    m, n_runs = kv.key_image(depth, float(intrinsics.fx), float(intrinsics.fy), float(intrinsics.cx),
                             float(intrinsics.cy), int(pixel_stride), float(min_depth_m), float(max_depth_m),
                             1.0 / float(voxel_size_m), box, pixel_key, cellcount, runs)
    return depth, pixel_key, cellcount, int(m), runs[: n_runs + 1]


def drop_flying_pixels(
    depth_m: np.ndarray,
    *,
    noise_model: str,
    noise_coeff: float,
    k_sigmas: float,
    workspace: Workspace | None = None,
) -> np.ndarray:
    """``depth_m`` with NaN at every pixel beside a depth jump: a valid 4-neighbour farther from it than
    ``max(k_sigmas * sigma(z), FLYING_MIN_REL * z)`` (``sigma`` the noise law ``noise_coeff * z**k`` of
    ``noise_model``). That drops flying pixels (depths between two surfaces, which real sensors report on the far
    side of an occluding edge and which a plane's noise band at long range would take in) together with the
    pixels either side of the edge. Invalid pixels (0, NaN, inf, negative) stay as they are.

    Returns an (H, W) float32 array (a workspace buffer when ``workspace`` is given: valid until the next call).
    """
    depth = np.asarray(depth_m)
    if depth.ndim != 2:
        raise ValueError(f"depth_m: expected an (H, W) image, got shape {depth.shape}")
    if not (isinstance(k_sigmas, (int, float)) and math.isfinite(k_sigmas) and k_sigmas > 0):
        raise ValueError(f"k_sigmas: expected a finite number > 0, got {k_sigmas!r}")
    power = noise_law_code(noise_model)
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    out = fresh(workspace).get("bp_unflying", depth.shape, np.float32)
    kv.drop_flying(depth, int(power), float(noise_coeff), float(k_sigmas), FLYING_MIN_REL, out)
    return out
