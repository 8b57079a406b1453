"""Numba kernels: depth image to points, and points grouped by voxel with a counting sort.

Voxel ``(ix, iy, iz) = floor(p / size)`` (the grid is anchored at the origin, so it does not depend on the data).
Inside a key box ``[x0, y0, z0, nx, ny, nz]`` a cell has the linear key ``((ix - x0) * ny + (iy - y0)) * nz +
(iz - z0)``. For a depth frame the box is the viewing frustum (known before any pixel is read), so
:func:`key_image` keys and counts the pixels before any point is stored and :func:`scatter_image` writes the points
straight to their voxel's place; for a point cloud it is the bounding box of the points (:func:`voxel_box`,
:func:`count_keys`). A small box indexes a dense cell table
(:func:`scatter_dense`); a huge one goes through an open-addressing hash table (:func:`voxelize_hash`). Either way
voxel ids follow the key order, so the result does not depend on the order of the points, and the points are copied
voxel by voxel into contiguous arrays (a stable counting sort: no comparison sort over the points).
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup

EMPTY = -1


@njit(error_model="numpy")
def backproject(depth, fx, fy, cx, cy, stride, z_min, z_max, pts, pix):
    """Back-project the valid pixels of ``depth`` (H, W) float32 into ``pts`` (M, 3) float32 and their flat pixel
    index ``v * W + u`` into ``pix`` (M,) int32; returns the number written.

    Valid: finite, > 0 and within ``[z_min, z_max]`` (NaN, inf, 0 and negatives fail the comparisons and are
    dropped). Every ``stride``-th pixel in both directions, starting at (0, 0).
    """
    h, w = depth.shape
    m = 0
    inv_fx = 1.0 / fx
    for v in range(0, h, stride):
        yf = (v - cy) / fy
        for u in range(0, w, stride):
            z = depth[v, u]
            if z > 0.0 and z >= z_min and z <= z_max:
                pts[m, 0] = (u - cx) * inv_fx * z
                pts[m, 1] = yf * z
                pts[m, 2] = z
                pix[m] = v * w + u
                m += 1
    return m


@njit(error_model="numpy", inline="always")
def _flying(z, zl, zr, zu, zd, c0, c1, c2, r):
    """``z`` itself, or NaN when it is valid and a valid neighbour is farther than its jump threshold."""
    inf = np.float32(np.inf)
    tau = max(c0 + z * (c1 + z * c2), r * z)
    bad = ((abs(z - zl) > tau) & (zl > 0) & (zl < inf)) | ((abs(z - zr) > tau) & (zr > 0) & (zr < inf))
    bad |= ((abs(z - zu) > tau) & (zu > 0) & (zu < inf)) | ((abs(z - zd) > tau) & (zd > 0) & (zd < inf))
    return np.float32(np.nan) if bad & (z > 0) & (z < inf) else z


@njit(error_model="numpy")
def drop_flying(depth, power, coeff, k_sigmas, rel, out):
    """``out`` (H, W) float32: ``depth`` with NaN at every valid pixel beside a depth jump, i.e. one with a valid
    4-neighbour farther from it than ``max(k_sigmas * coeff * z**power, rel * z)``: flying pixels (a depth between
    two surfaces, on the far side of an occluding edge) and the pixels either side of the edge. A pixel is valid when
    its depth is finite and > 0; invalid pixels are copied as they are and never count as neighbours. Float32
    arithmetic; a neighbour outside the image is the pixel itself. The inner columns run branch-free (vectorised)."""
    h, w = depth.shape
    k = coeff * k_sigmas
    c0 = np.float32(k if power == 0 else 0.0)
    c1 = np.float32(k if power == 1 else 0.0)
    c2 = np.float32(k if power == 2 else 0.0)
    r = np.float32(rel)
    flat = depth.reshape(-1)
    res = out.reshape(-1)
    for v in range(h):
        row = v * w
        up = (v - 1) * w if v > 0 else row
        dn = (v + 1) * w if v + 1 < h else row
        for u in (0, w - 1):
            if u < 0:
                continue
            ul = u - 1 if u > 0 else u
            ur = u + 1 if u + 1 < w else u
            res[row + u] = _flying(flat[row + u], flat[row + ul], flat[row + ur], flat[up + u], flat[dn + u],
                                   c0, c1, c2, r)
        for u in range(1, w - 1):
            i = np.uint64(row + u)
            res[i] = _flying(flat[i], flat[i - np.uint64(1)], flat[i + np.uint64(1)], flat[np.uint64(up + u)],
                             flat[np.uint64(dn + u)], c0, c1, c2, r)


@njit(error_model="numpy")
def _row_keys(depth, v, stride, yf, cx, inv_fx, z_min, z_max, inv_size, bx, by, bz, nyz, nz, ncell, pixel_key, i0):
    """Keys of the pixels of row ``v`` (see :func:`key_image`) into ``pixel_key[i0:]``, without a branch: the loop
    vectorises (6x faster than a scalar one)."""
    w = depth.shape[1]
    if stride == 1:
        for u in range(w):
            z = depth[v, u]
            ok = z > 0.0 and z >= z_min and z <= z_max
            px = np.float32((u - cx) * inv_fx * z)
            py = np.float32(yf * z)
            k = int(px * inv_size - bx) * nyz + int(py * inv_size - by) * nz + int(z * inv_size - bz)
            inside = k >= 0 and k < ncell
            pixel_key[i0 + u] = (k if inside else 0) if ok else -1
        return
    for iu in range((w + stride - 1) // stride):
        u = iu * stride
        z = depth[v, u]
        ok = z > 0.0 and z >= z_min and z <= z_max
        px = np.float32((u - cx) * inv_fx * z)
        py = np.float32(yf * z)
        k = int(px * inv_size - bx) * nyz + int(py * inv_size - by) * nz + int(z * inv_size - bz)
        inside = k >= 0 and k < ncell
        pixel_key[i0 + iu] = (k if inside else 0) if ok else -1


@njit(error_model="numpy")
def _image_keys(depth, stride, fy, cx, cy, inv_fx, z_min, z_max, inv_size, bx, by, bz, nyz, nz, ncell, pixel_key):
    h, w = depth.shape
    if stride == 1:
        dflat = depth.reshape(-1)  # C-contiguous: a flat view, unsigned indices
        for v in range(h):
            yf = (v - cy) / fy
            i0 = v * w
            for u in range(w):
                z = dflat[np.uint64(i0 + u)]
                ok = z > 0.0 and z >= z_min and z <= z_max
                px = np.float32((u - cx) * inv_fx * z)
                py = np.float32(yf * z)
                k = int(px * inv_size - bx) * nyz + int(py * inv_size - by) * nz + int(z * inv_size - bz)
                inside = k >= 0 and k < ncell
                pixel_key[np.uint64(i0 + u)] = (k if inside else 0) if ok else -1
        return
    wr = (w + stride - 1) // stride
    i0 = 0
    for v in range(0, h, stride):
        _row_keys(depth, v, stride, (v - cy) / fy, cx, inv_fx, z_min, z_max, inv_size, bx, by, bz, nyz, nz, ncell,
                  pixel_key, i0)
        i0 += wr


@njit(error_model="numpy")
def _run_starts(pixel_key, rows, wr, runs):
    """Where each run of equal keys starts in ``pixel_key`` (``rows`` rows of ``wr`` keys; a row always starts a
    run) into ``runs``, with ``runs[n_runs] = rows * wr``; returns ``n_runs``. Branch-free (a run starts about every
    7 pixels of a 640x480 frame: a surface near a cell face flickers between two cells, so a branch per key would
    mispredict there)."""
    nr = 0
    for v in range(rows):
        i0 = v * wr
        last = np.int32(-2)  # no key: the row's first pixel starts a run
        for u in range(wr):
            i = i0 + u
            k = pixel_key[np.uint64(i)]  # unsigned indices: no test for an index from the end
            runs[np.uint64(nr)] = i
            nr += 1 if k != last else 0
            last = k
    runs[nr] = rows * wr
    return nr


@njit(error_model="numpy")
def key_image(depth, fx, fy, cx, cy, stride, z_min, z_max, inv_size, box, pixel_key, cellcount, runs):
    """First pass of the image-order voxelization: the dense voxel key of every ``stride``-th pixel of ``depth``
    (H, W) float32, C-contiguous, into ``pixel_key`` (ceil(H/stride) * ceil(W/stride),) int32, -1 where the depth is
    invalid (as :func:`backproject`), where each run of equal keys starts into ``runs`` (that size + 1, int32; see
    :func:`_run_starts`) and the points per cell into ``cellcount`` (``nx*ny*nz`` int32, zeroed here). No point
    is stored: :func:`scatter_image` computes them again, straight into their voxel's place. Returns the number
    of valid pixels and the number of runs. ``box`` must contain every valid point's cell (the viewing frustum
    between ``z_min`` and ``z_max``, see ``frustum_box``, with a one-cell margin); keys are clamped to it, which only
    guards the memory."""
    ncell = box[3] * box[4] * box[5]
    for c in range(ncell):
        cellcount[c] = 0
    h, w = depth.shape
    wr = (w + stride - 1) // stride
    inv_fx = 1.0 / fx
    _image_keys(depth, stride, fy, cx, cy, inv_fx, z_min, z_max, inv_size, float(box[0]), float(box[1]),
                float(box[2]), box[4] * box[5], box[5], ncell, pixel_key)
    nr = _run_starts(pixel_key, (h + stride - 1) // stride, wr, runs)
    # Counted run by run: a cell's count goes through memory once per run, not once per pixel.
    m = 0
    for r in range(nr):
        a = runs[r]
        k = pixel_key[np.uint64(a)]
        if k >= 0:
            n = runs[r + 1] - a
            cellcount[np.uint64(k)] += n
            m += n
    return m, nr


@njit(error_model="numpy")
def _number_voxels(cellmap, ncell, voxel_key, voxel_start):
    """Occupied cells in key order become voxels: ``cellmap`` (points per cell on entry) holds each cell's voxel id
    on return (``EMPTY`` for none), ``voxel_key[:V]`` the cells, ``voxel_start[:V + 1]`` the offsets of their
    points. Returns ``V``."""
    nv = 0
    run = 0
    for c in range(ncell):
        cnt = cellmap[c]
        if cnt > 0:
            voxel_key[nv] = c
            voxel_start[nv] = run
            run += cnt
            cellmap[c] = nv
            nv += 1
        else:
            cellmap[c] = EMPTY
    voxel_start[nv] = run
    return nv


@njit(error_model="numpy")
def scatter_image(depth, fx, fy, cx, cy, stride, pixel_key, runs, n_runs, cellmap, box, voxel_key, voxel_start,
                  sorted_pts, sorted_src):
    """Second pass of the image-order voxelization: every valid pixel's point (as :func:`backproject`) written
    straight to its voxel's place (``depth`` and ``sorted_pts`` C-contiguous), run by run (``runs[:n_runs + 1]``
    from :func:`key_image`: a run's points go to consecutive places, with no test per pixel). ``cellmap`` holds the
    points per cell on entry (from :func:`key_image`) and the voxel id of each cell on return; outputs as
    :func:`scatter_dense`, except that ``sorted_src`` holds each point's flat pixel index ``v * W + u`` (points of a
    voxel in raster order). Returns the number of voxels."""
    nv = _number_voxels(cellmap, box[3] * box[4] * box[5], voxel_key, voxel_start)
    cursor = np.empty(nv, np.int64)
    for v in range(nv):
        cursor[v] = voxel_start[v]
    w = depth.shape[1]
    inv_fx = 1.0 / fx
    wr = (w + stride - 1) // stride
    # (u - cx) / fx once per column: the same float64 product as in backproject, so the same float32 points.
    xf = np.empty(wr)
    for iu in range(wr):
        xf[iu] = (iu * stride - cx) * inv_fx
    # Flat views and unsigned indices: no stride products and no test for an index from the end.
    flat = sorted_pts.reshape(-1)
    dflat = depth.reshape(-1)
    for r in range(n_runs):
        a = runs[r]
        key = pixel_key[np.uint64(a)]
        if key < 0:
            continue
        n = runs[r + 1] - a
        vr = a // wr  # a run lies in one row
        iu0 = a - vr * wr
        v = vr * stride
        yf = (v - cy) / fy
        src0 = v * w + iu0 * stride
        c = np.uint64(cellmap[np.uint64(key)])
        j0 = cursor[c]
        cursor[c] = j0 + n
        for i in range(n):  # as fast as a loop of its own for stride 1 (timed)
            z = dflat[np.uint64(src0 + i * stride)]
            j3 = np.uint64(3 * (j0 + i))
            flat[j3] = np.float32(xf[np.uint64(iu0 + i)] * z)
            flat[j3 + np.uint64(1)] = np.float32(yf * z)
            flat[j3 + np.uint64(2)] = z
            sorted_src[np.uint64(j0 + i)] = src0 + i * stride
    return nv


@njit(error_model="numpy")
def count_keys(pts, m, inv_size, box, point_key, cellcount):
    """Dense voxel key of each of ``pts[:m]`` into ``point_key`` and points per cell into ``cellcount`` (zeroed)."""
    ncell = box[3] * box[4] * box[5]
    for c in range(ncell):
        cellcount[c] = 0
    for i in range(m):
        k = _key(pts[i, 0], pts[i, 1], pts[i, 2], inv_size, box)
        point_key[i] = k
        cellcount[k] += 1


@njit(error_model="numpy")
def scatter_dense(pts, m, point_key, cellmap, box, voxel_key, voxel_start, sorted_pts, sorted_src):
    """Counting sort of ``pts[:m]`` by dense key. Returns the number of voxels ``V``.

    ``cellmap`` holds the points per cell on entry (from :func:`count_keys`) and the
    voxel id of each cell (-1 for empty) on return. Outputs: ``voxel_key[:V]`` increasing, ``voxel_start[:V + 1]``
    offsets into ``sorted_pts`` / ``sorted_src`` (the points and their index in ``pts``, voxel by voxel, in input
    order inside a voxel).
    """
    nv = _number_voxels(cellmap, box[3] * box[4] * box[5], voxel_key, voxel_start)
    cursor = np.empty(nv, np.int64)
    for v in range(nv):
        cursor[v] = voxel_start[v]
    # Runs of points of one cell (neighbouring pixels) advance a register, not the cell's cursor in memory.
    last = -1
    j = 0
    for i in range(m):
        key = point_key[i]
        if key != last:
            if last >= 0:
                cursor[cellmap[last]] = j
            last = key
            j = cursor[cellmap[key]]
        sorted_pts[j, 0] = pts[i, 0]
        sorted_pts[j, 1] = pts[i, 1]
        sorted_pts[j, 2] = pts[i, 2]
        sorted_src[j] = i
        j += 1
    return nv


@njit(error_model="numpy")
def voxel_box(pts, m, inv_size):
    """Integer bounds ``(x0, y0, z0, x1, y1, z1)`` (inclusive) of the voxel coordinates of ``pts[:m]``."""
    x0 = y0 = z0 = np.iinfo(np.int64).max
    x1 = y1 = z1 = np.iinfo(np.int64).min
    for i in range(m):
        ix = int(math.floor(pts[i, 0] * inv_size))
        iy = int(math.floor(pts[i, 1] * inv_size))
        iz = int(math.floor(pts[i, 2] * inv_size))
        x0 = min(x0, ix)
        y0 = min(y0, iy)
        z0 = min(z0, iz)
        x1 = max(x1, ix)
        y1 = max(y1, iy)
        z1 = max(z1, iz)
    return x0, y0, z0, x1, y1, z1


@njit(error_model="numpy")
def _key(px, py, pz, inv_size, box):
    ix = int(math.floor(px * inv_size)) - box[0]
    iy = int(math.floor(py * inv_size)) - box[1]
    iz = int(math.floor(pz * inv_size)) - box[2]
    return (ix * box[4] + iy) * box[5] + iz


@njit(error_model="numpy")
def _hash(key, mask):
    # Fibonacci hashing of a non-negative int64 key.
    h = (key * -7046029254386353131) & 0x7FFFFFFFFFFFFFFF  # 0x9E3779B97F4A7C15 as int64
    return (h >> 17) & mask


@njit(error_model="numpy")
def hash_find(tkeys, key):
    """Slot of ``key`` in the open-addressing table ``tkeys`` (size a power of two), or -1."""
    mask = tkeys.shape[0] - 1
    s = _hash(key, mask)
    while True:
        k = tkeys[s]
        if k == key:
            return s
        if k == EMPTY:
            return -1
        s = (s + 1) & mask


@njit(error_model="numpy")
def voxelize_hash(pts, m, inv_size, box, tkeys, tvals, point_key, voxel_key, voxel_start, sorted_pts, sorted_src):
    """Group ``pts[:m]`` by voxel through the open-addressing table ``tkeys`` (T int64, filled with -1 here) /
    ``tvals`` (T int32), ``T`` a power of two >= 2 m, for key boxes too large for a dense table. Returns ``V``.

    Outputs as :func:`scatter_dense`; on return ``tvals`` maps each
    key's slot to its voxel id. Voxel ids follow the key order (the occupied keys are sorted: V log V, not M).
    """
    mask = tkeys.shape[0] - 1
    for s in range(tkeys.shape[0]):
        tkeys[s] = EMPTY
    nv = 0
    for i in range(m):
        k = _key(pts[i, 0], pts[i, 1], pts[i, 2], inv_size, box)
        s = _hash(k, mask)
        while True:
            tk = tkeys[s]
            if tk == k:
                tvals[s] += 1
                break
            if tk == EMPTY:
                tkeys[s] = k
                tvals[s] = 1
                nv += 1
                break
            s = (s + 1) & mask
        point_key[i] = s  # the slot: the scatter below needs no second probe
    slots = np.empty(nv, np.int64)
    j = 0
    for s in range(tkeys.shape[0]):
        if tkeys[s] != EMPTY:
            slots[j] = s
            voxel_key[j] = tkeys[s]
            j += 1
    order = np.argsort(voxel_key[:nv])
    cursor = np.empty(nv, np.int64)
    keys_sorted = voxel_key[:nv][order]
    run = 0
    for v in range(nv):
        s = slots[order[v]]
        voxel_key[v] = keys_sorted[v]
        voxel_start[v] = run
        cursor[v] = run
        run += tvals[s]
        tvals[s] = v
    voxel_start[nv] = run
    for i in range(m):
        v = tvals[point_key[i]]
        j = cursor[v]
        cursor[v] = j + 1
        sorted_pts[j, 0] = pts[i, 0]
        sorted_pts[j, 1] = pts[i, 1]
        sorted_pts[j, 2] = pts[i, 2]
        sorted_src[j] = i
    return nv


@njit(error_model="numpy")
def voxel_lookup(ix, iy, iz, box, dense, cellmap, tkeys, tvals):
    """Voxel id of the cell ``(ix, iy, iz)`` relative to the box origin, or -1 (outside the box or empty)."""
    if ix < 0 or iy < 0 or iz < 0 or ix >= box[3] or iy >= box[4] or iz >= box[5]:
        return -1
    k = (ix * box[4] + iy) * box[5] + iz
    if dense:
        return cellmap[k]
    s = hash_find(tkeys, k)
    if s < 0:
        return -1
    return tvals[s]


@njit(fastmath={"reassoc", "contract"}, error_model="numpy")
def voxel_moments(sorted_pts, voxel_start, nv, counts, sums, scatters):
    """Per voxel: point count, sum of points and sum of ``p p^T`` (about the origin), float64, from the sorted
    points (accumulated about the voxel's first point, which keeps millimetre noise at any distance).

    Reassociated sums (``fastmath`` reassoc/contract, no NaN/inf assumptions) vectorise: 2x faster, same values to
    rounding.
    """
    # A flat view (C-contiguous points) and unsigned indices (no test for an index from the end): 2x faster again,
    # the same sums (the same vectorised order).
    flat = sorted_pts.reshape(-1)
    for v in range(nv):
        a = voxel_start[v]
        b = voxel_start[v + 1]
        rx = np.float64(sorted_pts[a, 0])
        ry = np.float64(sorted_pts[a, 1])
        rz = np.float64(sorted_pts[a, 2])
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
        for j in range(a, b):
            j3 = np.uint64(3 * j)
            x = flat[j3] - rx
            y = flat[j3 + np.uint64(1)] - ry
            z = flat[j3 + np.uint64(2)] - rz
            s0 += x
            s1 += y
            s2 += z
            s3 += x * x
            s4 += x * y
            s5 += x * z
            s6 += y * y
            s7 += y * z
            s8 += z * z
        n = b - a
        counts[v] = n
        # sum p = s + n r;  sum p p^T = S + s r^T + r s^T + n r r^T
        sums[v, 0] = s0 + n * rx
        sums[v, 1] = s1 + n * ry
        sums[v, 2] = s2 + n * rz
        scatters[v, 0, 0] = s3 + 2.0 * s0 * rx + n * rx * rx
        scatters[v, 0, 1] = s4 + s0 * ry + rx * s1 + n * rx * ry
        scatters[v, 0, 2] = s5 + s0 * rz + rx * s2 + n * rx * rz
        scatters[v, 1, 1] = s6 + 2.0 * s1 * ry + n * ry * ry
        scatters[v, 1, 2] = s7 + s1 * rz + ry * s2 + n * ry * rz
        scatters[v, 2, 2] = s8 + 2.0 * s2 * rz + n * rz * rz
        scatters[v, 1, 0] = scatters[v, 0, 1]
        scatters[v, 2, 0] = scatters[v, 0, 2]
        scatters[v, 2, 1] = scatters[v, 1, 2]


@register_warmup
def _warmup() -> None:
    depth = np.full((4, 5), 2.0, np.float32)
    depth[0, 0] = np.nan
    pts = np.empty((20, 3), np.float32)
    pix = np.empty(20, np.int32)
    m = backproject(depth, 5.0, 5.0, 2.0, 1.5, 1, 0.1, 10.0, pts, pix)
    box = voxel_box(pts, m, 4.0)
    b = np.array([box[0], box[1], box[2], box[3] - box[0] + 1, box[4] - box[1] + 1, box[5] - box[2] + 1], np.int64)
    cellmap = np.empty(int(b[3] * b[4] * b[5]), np.int32)
    pkey = np.empty(m, np.int64)
    pkey32 = np.empty(20, np.int32)
    runs = np.empty(21, np.int32)
    _, n_runs = key_image(depth, 5.0, 5.0, 2.0, 1.5, 1, 0.1, 10.0, 4.0, b, pkey32, cellmap, runs)
    drop_flying(depth, 2, 1.4e-3, 4.0, 0.03, np.empty_like(depth))
    scatter_image(depth, 5.0, 5.0, 2.0, 1.5, 1, pkey32, runs, n_runs, cellmap, b, np.empty(m, np.int64),
                  np.empty(m + 1, np.int64), np.empty((m, 3), np.float32), np.empty(m, np.int32))
    count_keys(pts, m, 4.0, b, pkey, cellmap)
    vkey = np.empty(m, np.int64)
    vstart = np.empty(m + 1, np.int64)
    spts = np.empty((m, 3), np.float32)
    ssrc = np.empty(m, np.int32)
    counts = np.empty(m, np.int64)
    sums = np.empty((m, 3))
    scat = np.empty((m, 3, 3))
    nv = scatter_dense(pts, m, pkey, cellmap, b, vkey, vstart, spts, ssrc)
    voxel_moments(spts, vstart, nv, counts, sums, scat)
    tkeys = np.empty(64, np.int64)
    tvals = np.empty(64, np.int32)
    nv = voxelize_hash(pts, m, 4.0, b, tkeys, tvals, pkey, vkey, vstart, spts, ssrc)
    voxel_moments(spts, vstart, nv, counts, sums, scat)
    for dense in (True, False):
        voxel_lookup(0, 0, 0, b, dense, cellmap, tkeys, tvals)
