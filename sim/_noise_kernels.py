"""Numba kernels of the depth noise models (see sim/noise.py for the models).

The random draws come in as arrays (made by a seeded NumPy Generator), so results depend only on the seed; the
kernels do the per-pixel arithmetic without temporaries.
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup

KIND_NONE = 0
KIND_KINECT = 1
KIND_STEREO = 2
KIND_TOF = 3


@njit
def _nearer_neighbour(z, r, c):
    """Smallest finite depth among the 4 neighbours of (r, c), inf when none."""
    H, W = z.shape
    best = np.inf
    if r > 0 and z[r - 1, c] < best:
        best = z[r - 1, c]
    if r + 1 < H and z[r + 1, c] < best:
        best = z[r + 1, c]
    if c > 0 and z[r, c - 1] < best:
        best = z[r, c - 1]
    if c + 1 < W and z[r, c + 1] < best:
        best = z[r, c + 1]
    return best


@njit
def flying_candidates(z, rel, out):
    """``out`` (H, W) bool: pixels with a neighbour nearer by more than ``rel * z`` (the far side of a jump).
    NaN depths count as no surface. Returns the number of candidates.

    The same test as :func:`_nearer_neighbour` per pixel, on flat views of the arrays (C-contiguous, else numba's
    reshape raises rather than write into a copy): indexing them in 2-D through the helper took 7 times as long (1.6
    against 0.24 ms a 320 x 240 frame), a third of the simulated camera's time in a profile of the demo."""
    H, W = z.shape
    zf = z.reshape(H * W)
    of = out.reshape(H * W)
    keep = 1.0 - rel
    n = 0
    for r in range(H):
        base = r * W
        for c in range(W):
            i = base + c
            zz = zf[i]
            hit = False
            if zz == zz:
                near = np.inf
                if r > 0 and zf[i - W] < near:
                    near = zf[i - W]
                if r + 1 < H and zf[i + W] < near:
                    near = zf[i + W]
                if c > 0 and zf[i - 1] < near:
                    near = zf[i - 1]
                if c + 1 < W and zf[i + 1] < near:
                    near = zf[i + 1]
                hit = near < zz * keep
            of[i] = hit
            if hit:
                n += 1
    return n


@njit
def apply_noise(
    z_true, labels, kind, gauss, u_miss, cand, u_fly, a_fly,
    min_range, max_range, missing, p_fly,
    kinect_coeff, focal_baseline, sigma_disp, steps, tof_a, tof_b, tof_edge, tof_edge_missing, cx, cy, inv_rmax2,
    out_depth, out_labels,
):
    """Noisy depth and surviving labels, in place into ``out_depth`` (H, W) float32 / ``out_labels`` (H, W) int32.

    ``gauss`` and ``u_miss`` (H, W) are standard normal and uniform draws; ``cand`` marks flying-pixel candidates
    (raster order) whose uniforms are ``u_fly`` / ``a_fly`` (K,). A flying pixel reports
    ``near + (0.1 + 0.8 a) (z - near)`` and loses its label; missing and out-of-range pixels become NaN, label 0.
    """
    H, W = z_true.shape
    k = 0
    for r in range(H):
        for c in range(W):
            z = z_true[r, c]
            if not (z == z) or z <= 0.0:
                out_depth[r, c] = np.nan
                out_labels[r, c] = 0
                continue
            lab = labels[r, c]
            r2 = 0.0
            if kind == KIND_TOF:
                du = c - cx
                dv = r - cy
                r2 = (du * du + dv * dv) * inv_rmax2
            fly = False
            if cand[r, c]:
                if u_fly[k] < p_fly:
                    fly = True
                    near = _nearer_neighbour(z_true, r, c)
                    val = near + (0.1 + 0.8 * a_fly[k]) * (z - near)
                k += 1
            if not fly:
                g = gauss[r, c]
                if kind == KIND_KINECT:
                    val = z + g * kinect_coeff * z * z
                elif kind == KIND_TOF:
                    val = z + g * (tof_a + tof_b * z) * (1.0 + tof_edge * r2)
                elif kind == KIND_STEREO:
                    disp = focal_baseline / z + g * sigma_disp
                    disp = math.floor(disp * steps + 0.5) / steps
                    val = focal_baseline / disp if disp > 0.0 else np.nan
                else:
                    val = z
            p = missing
            if kind == KIND_TOF:
                p += tof_edge_missing * r2 * r2
            keep = u_miss[r, c] >= p and val >= min_range and val <= max_range and z <= max_range
            if keep:
                out_depth[r, c] = val
                out_labels[r, c] = 0 if fly else lab
            else:
                out_depth[r, c] = np.nan
                out_labels[r, c] = 0


@register_warmup
def _warmup() -> None:
    z = np.full((3, 3), 2.0, np.float32)
    z[1, 1] = 1.0
    lab = np.ones((3, 3), np.int32)
    cand = np.zeros((3, 3), np.bool_)
    n = flying_candidates(z, 0.05, cand)
    g = np.zeros((3, 3), np.float32)
    u = np.ones((3, 3), np.float32)
    uf = np.zeros(n, np.float32)
    od = np.empty((3, 3), np.float32)
    ol = np.empty((3, 3), np.int32)
    apply_noise(z, lab, KIND_KINECT, g, u, cand, uf, uf, 0.1, 10.0, 0.0, 0.5, 1.4e-3, 30.0, 0.1, 8.0,
                2e-3, 2e-3, 1.5, 0.08, 1.0, 1.0, 0.5, od, ol)
