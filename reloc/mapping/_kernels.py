"""Numba kernels of map building: carving the free space a depth frame saw, and the per-voxel sample bookkeeping of
plane fusion (arrays in, arrays out)."""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup
from reloc.matching._kernels import _lower_bound

# numba caches a kernel with the kernels it calls compiled in, keyed on this file's stamp only: a change to
# _lower_bound in matching/_kernels goes with an edit here.

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


@njit
def count_touching(keys_q, keys_m, offsets):
    """How many of the voxel keys ``keys_q`` have a key of the sorted array ``keys_m`` among their neighbours
    (``keys_q[i] + offsets[o]``: keys are packed so that offsets add, see ``fusion.voxel_keys``)."""
    n = 0
    nm = keys_m.shape[0]
    for i in range(keys_q.shape[0]):
        for o in range(offsets.shape[0]):
            key = keys_q[i] + offsets[o]
            at = _lower_bound(keys_m, 0, nm, key)
            if at < nm and keys_m[at] == key:
                n += 1
                break
    return n


@njit
def touching_both_ways(keys_q, keys_m, offsets, hit_q, near_m):
    """How many of the sorted voxel keys ``keys_q`` have a key of the sorted array ``keys_m`` among their neighbours
    (as :func:`count_touching`), marking them in ``hit_q``, and, in ``near_m``, which keys of ``keys_m`` are
    neighbours of a key of ``keys_q`` (both bool arrays, cleared first). Per offset the shifted keys stay sorted, so
    each search gallops on from where the last one ended: about ``len(keys_q) * log(len(keys_m) / len(keys_q))``
    steps per offset, far fewer than a binary search each when the two planes are alike (a submap's frames)."""
    nm = keys_m.shape[0]
    nq = keys_q.shape[0]
    for j in range(nm):
        near_m[j] = False
    for i in range(nq):
        hit_q[i] = False
    for o in range(offsets.shape[0]):
        lo = 0
        for i in range(nq):
            if lo >= nm:
                break
            key = keys_q[i] + offsets[o]
            b = 1
            while lo + b - 1 < nm and keys_m[lo + b - 1] < key:
                b *= 2
            at = _lower_bound(keys_m, lo + b // 2, min(lo + b - 1, nm), key) if b > 1 else lo
            if at < nm and keys_m[at] == key:
                near_m[at] = True
                hit_q[i] = True
            lo = at
    n = 0
    for i in range(nq):
        if hit_q[i]:
            n += 1
    return n


@njit
def voxel_sums(keys, points, order, keys_out, sums_out, counts_out):
    """Per distinct key of ``keys`` (N,): the sum of its ``points`` (N, 3) and their number, in increasing key order.

    ``order`` is a stable argsort of ``keys``, so each voxel's points are added in their input order (the figures
    ``np.unique`` with ``np.bincount`` give, to the last bit). Returns the number of distinct keys written."""
    k = -1
    last = np.int64(0)
    for r in range(order.shape[0]):
        i = order[r]
        key = keys[i]
        if k < 0 or key != last:
            k += 1
            keys_out[k] = key
            sums_out[k, 0] = 0.0
            sums_out[k, 1] = 0.0
            sums_out[k, 2] = 0.0
            counts_out[k] = 0.0
            last = key
        sums_out[k, 0] += points[i, 0]
        sums_out[k, 1] += points[i, 1]
        sums_out[k, 2] += points[i, 2]
        counts_out[k] += 1.0
    return k + 1


@njit
def merge_voxel_sums(keys_a, sums_a, counts_a, keys_b, sums_b, counts_b, keys_out, sums_out, counts_out):
    """Two planes' per-voxel sample sums (sorted distinct keys) merged into one: a voxel both hold gets the sum of
    the two (``a + b``, as ``np.bincount`` over the concatenation adds them). Returns the number of keys written."""
    na = keys_a.shape[0]
    nb = keys_b.shape[0]
    i = 0
    j = 0
    n = 0
    while i < na or j < nb:
        if j >= nb or (i < na and keys_a[i] < keys_b[j]):
            keys_out[n] = keys_a[i]
            for c in range(3):
                sums_out[n, c] = sums_a[i, c]
            counts_out[n] = counts_a[i]
            i += 1
        elif i >= na or keys_b[j] < keys_a[i]:
            keys_out[n] = keys_b[j]
            for c in range(3):
                sums_out[n, c] = sums_b[j, c]
            counts_out[n] = counts_b[j]
            j += 1
        else:
            keys_out[n] = keys_a[i]
            for c in range(3):
                sums_out[n, c] = sums_a[i, c] + sums_b[j, c]
            counts_out[n] = counts_a[i] + counts_b[j]
            i += 1
            j += 1
        n += 1
    return n


@register_warmup
def _warmup() -> None:
    depth = np.full((4, 4), 2.0, np.float32)
    out = np.empty(1000, np.int64)
    carve_free_space(depth, 2.0, 2.0, 2.0, 2.0, np.eye(3), np.zeros(3), 1, 0.2, 0.3, 5.0, out)
    keys = np.array([3, 1, 3], np.int64)
    pts = np.ones((3, 3))
    ko = np.empty(3, np.int64)
    so = np.empty((3, 3))
    co = np.empty(3)
    n = voxel_sums(keys, pts, np.argsort(keys, kind="stable"), ko, so, co)
    count_touching(ko[:n], ko[:n], np.zeros(1, np.int64))
    touching_both_ways(ko[:n], ko[:n], np.zeros(1, np.int64), np.empty(n, np.bool_), np.empty(n, np.bool_))
    k2 = np.empty(4, np.int64)
    merge_voxel_sums(ko[:n], so[:n], co[:n], ko[:n], so[:n], co[:n], k2, np.empty((4, 3)), np.empty(4))
