"""Numba kernels of the depth renderer: z-buffer rasterization of convex planar polygons, ray casting of clutter.

Arrays in, arrays out, no classes. Depth is the optical-axis depth ``z`` of the camera frame (x right, y down,
z forward) at pixel centres: pixel ``(u, v)`` looks along ``((u - cx) / fx, (v - cy) / fy, 1)``.

Polygons are rasterized exactly: each convex polygon is moved into the camera frame, clipped against the near plane
``z = near``, projected, and every pixel whose centre lies inside the projected polygon (edges inclusive, so
polygons sharing an edge leave no crack) takes the depth of the ray meeting the polygon's plane. Row spans come
from the edge equations, so the inner loop is one division per pixel. Vertical cylinders and spheres are ray cast
inside the image box of their bounding box.
"""

from __future__ import annotations

import math

import numpy as np

from reloc._numba import njit, register_warmup

# Pixels whose centre is this far outside an edge (in pixels) still count as inside: closes cracks between
# polygons that share an edge, whatever the rounding.
_EDGE_EPS_PX = 1e-6


@njit
def _clip_near(px, py, pz, n, near, ox, oy, oz):
    """Sutherland-Hodgman clip of the polygon (px, py, pz)[:n] against z >= near into (ox, oy, oz); returns count."""
    m = 0
    for i in range(n):
        j = (i + 1) % n
        zi = pz[i]
        zj = pz[j]
        in_i = zi >= near
        in_j = zj >= near
        if in_i:
            ox[m] = px[i]
            oy[m] = py[i]
            oz[m] = zi
            m += 1
        if in_i != in_j:
            s = (near - zi) / (zj - zi)
            ox[m] = px[i] + s * (px[j] - px[i])
            oy[m] = py[i] + s * (py[j] - py[i])
            oz[m] = near
            m += 1
    return m


@njit
def rasterize_polygons(
    R_cam_world, t_cam_world, fx, fy, cx, cy, near, far,
    poly_vertices, poly_ptr, poly_normals, poly_offsets, poly_labels,
    depth, labels,
):
    """Z-buffer the convex polygons into ``depth`` (H, W) float32 and ``labels`` (H, W) int32, in place.

    - ``R_cam_world`` (3, 3), ``t_cam_world`` (3,) float64: world to camera.
    - ``poly_vertices`` (V, 3) float64 world; polygon ``q`` is ``poly_vertices[poly_ptr[q]:poly_ptr[q + 1]]``,
      convex and planar, on the plane ``poly_normals[q] . p + poly_offsets[q] = 0`` (world).
    - ``poly_labels`` (Q,) int32 label written for the polygon's pixels.
    - ``depth`` must come in filled with +inf (or any z-buffer state); only nearer hits within (near, far) are
      written. Returns the number of polygons that reached the image.
    """
    H, W = depth.shape
    nq = poly_ptr.shape[0] - 1
    maxv = 0
    for q in range(nq):
        c = poly_ptr[q + 1] - poly_ptr[q]
        if c > maxv:
            maxv = c
    cap = maxv + 2
    px = np.empty(cap)
    py = np.empty(cap)
    pz = np.empty(cap)
    ox = np.empty(cap + 2)
    oy = np.empty(cap + 2)
    oz = np.empty(cap + 2)
    us = np.empty(cap + 2)
    vs = np.empty(cap + 2)
    ea = np.empty(cap + 2)
    eb = np.empty(cap + 2)
    ec = np.empty(cap + 2)
    inv_fx = 1.0 / fx
    inv_fy = 1.0 / fy
    drawn = 0
    for q in range(nq):
        s0 = poly_ptr[q]
        n = poly_ptr[q + 1] - s0
        if n < 3:
            continue
        # Plane in the camera frame: n_c = R n_w, d_c = d_w - n_c . t.
        nwx = poly_normals[q, 0]
        nwy = poly_normals[q, 1]
        nwz = poly_normals[q, 2]
        ncx = R_cam_world[0, 0] * nwx + R_cam_world[0, 1] * nwy + R_cam_world[0, 2] * nwz
        ncy = R_cam_world[1, 0] * nwx + R_cam_world[1, 1] * nwy + R_cam_world[1, 2] * nwz
        ncz = R_cam_world[2, 0] * nwx + R_cam_world[2, 1] * nwy + R_cam_world[2, 2] * nwz
        dc = poly_offsets[q] - (ncx * t_cam_world[0] + ncy * t_cam_world[1] + ncz * t_cam_world[2])
        if abs(dc) < 1e-9:
            continue  # the camera centre lies in the plane: seen edge-on, covers no pixel
        any_front = False
        for i in range(n):
            wx = poly_vertices[s0 + i, 0]
            wy = poly_vertices[s0 + i, 1]
            wz = poly_vertices[s0 + i, 2]
            px[i] = R_cam_world[0, 0] * wx + R_cam_world[0, 1] * wy + R_cam_world[0, 2] * wz + t_cam_world[0]
            py[i] = R_cam_world[1, 0] * wx + R_cam_world[1, 1] * wy + R_cam_world[1, 2] * wz + t_cam_world[1]
            pz[i] = R_cam_world[2, 0] * wx + R_cam_world[2, 1] * wy + R_cam_world[2, 2] * wz + t_cam_world[2]
            if pz[i] >= near:
                any_front = True
        if not any_front:
            continue
        m = _clip_near(px, py, pz, n, near, ox, oy, oz)
        if m < 3:
            continue
        umin = 1e300
        umax = -1e300
        vmin = 1e300
        vmax = -1e300
        for i in range(m):
            u = fx * ox[i] / oz[i] + cx
            v = fy * oy[i] / oz[i] + cy
            us[i] = u
            vs[i] = v
            umin = min(umin, u)
            umax = max(umax, u)
            vmin = min(vmin, v)
            vmax = max(vmax, v)
        r0 = max(0, int(math.ceil(vmin - _EDGE_EPS_PX)))
        r1 = min(H - 1, int(math.floor(vmax + _EDGE_EPS_PX)))
        c0 = max(0, int(math.ceil(umin - _EDGE_EPS_PX)))
        c1 = min(W - 1, int(math.floor(umax + _EDGE_EPS_PX)))
        if r0 > r1 or c0 > c1:
            continue
        # Orientation of the projected polygon (negative fy mirrors it).
        area2 = 0.0
        for i in range(m):
            j = (i + 1) % m
            area2 += us[i] * vs[j] - us[j] * vs[i]
        if abs(area2) < 1e-12:
            continue
        sgn = 1.0 if area2 > 0 else -1.0
        # Edge i: e(u, v) = a u + b v + c >= 0 inside, normalised so e is a distance in pixels.
        ne = 0
        for i in range(m):
            j = (i + 1) % m
            du = us[j] - us[i]
            dv = vs[j] - vs[i]
            ln = math.sqrt(du * du + dv * dv)
            if ln < 1e-12:
                continue
            a = -dv * sgn / ln
            b = du * sgn / ln
            ea[ne] = a
            eb[ne] = b
            ec[ne] = -(a * us[i] + b * vs[i])
            ne += 1
        hit = False
        for r in range(r0, r1 + 1):
            lo = float(c0)
            hi = float(c1)
            for k in range(ne):
                rhs = -(eb[k] * r + ec[k]) - _EDGE_EPS_PX  # need a u >= rhs
                a = ea[k]
                if a > 1e-12:
                    lo = max(lo, rhs / a)
                elif a < -1e-12:
                    hi = min(hi, rhs / a)
                elif rhs > 0.0:
                    hi = -1.0
                    break
            if hi < lo:
                continue
            u0 = max(c0, int(math.ceil(lo)))
            u1 = min(c1, int(math.floor(hi)))
            ry = (r - cy) * inv_fy
            base = ncy * ry + ncz
            for u in range(u0, u1 + 1):
                den = ncx * (u - cx) * inv_fx + base
                if den == 0.0:
                    continue
                z = -dc / den
                if z > near and z < far and z < depth[r, u]:
                    depth[r, u] = z
                    labels[r, u] = poly_labels[q]
                    hit = True
        if hit:
            drawn += 1
    return drawn


@njit
def _box_to_pixels(R, t, fx, fy, cx, cy, near, H, W, x0, y0, z0, x1, y1, z1, out):
    """Image box (r0, r1, c0, c1) of a world AABB into ``out``: empty when it is wholly behind the near plane, the
    whole image when it straddles it."""
    umin = 1e300
    umax = -1e300
    vmin = 1e300
    vmax = -1e300
    behind = 0
    for k in range(8):
        wx = x1 if (k & 1) else x0
        wy = y1 if (k & 2) else y0
        wz = z1 if (k & 4) else z0
        pcx = R[0, 0] * wx + R[0, 1] * wy + R[0, 2] * wz + t[0]
        pcy = R[1, 0] * wx + R[1, 1] * wy + R[1, 2] * wz + t[1]
        pcz = R[2, 0] * wx + R[2, 1] * wy + R[2, 2] * wz + t[2]
        if pcz < near:
            behind += 1
            continue
        u = fx * pcx / pcz + cx
        v = fy * pcy / pcz + cy
        umin = min(umin, u)
        umax = max(umax, u)
        vmin = min(vmin, v)
        vmax = max(vmax, v)
    if behind == 8:  # wholly behind the camera: an empty box
        out[0] = 0
        out[1] = -1
        out[2] = 0
        out[3] = -1
        return
    if behind > 0:  # straddles the near plane: no safe projection, take the whole image
        out[0] = 0
        out[1] = H - 1
        out[2] = 0
        out[3] = W - 1
        return
    out[0] = max(0, int(math.floor(vmin)))
    out[1] = min(H - 1, int(math.ceil(vmax)))
    out[2] = max(0, int(math.floor(umin)))
    out[3] = min(W - 1, int(math.ceil(umax)))


@njit
def raycast_clutter(
    R_cam_world, t_cam_world, fx, fy, cx, cy, near, far, cylinders, spheres, clutter_label, depth, labels,
):
    """Ray cast vertical cylinders ``(N, 5)`` rows ``[x, y, z_bottom, z_top, radius]`` (side and caps) and spheres
    ``(M, 4)`` rows ``[x, y, z, radius]`` (world) into the z-buffer ``depth`` / ``labels`` (label ``clutter_label``).
    """
    H, W = depth.shape
    # Camera centre and the rows of R^T (ray directions in the world).
    ox = -(R_cam_world[0, 0] * t_cam_world[0] + R_cam_world[1, 0] * t_cam_world[1] + R_cam_world[2, 0] * t_cam_world[2])
    oy = -(R_cam_world[0, 1] * t_cam_world[0] + R_cam_world[1, 1] * t_cam_world[1] + R_cam_world[2, 1] * t_cam_world[2])
    oz = -(R_cam_world[0, 2] * t_cam_world[0] + R_cam_world[1, 2] * t_cam_world[1] + R_cam_world[2, 2] * t_cam_world[2])
    box = np.empty(4, np.int64)
    inv_fx = 1.0 / fx
    inv_fy = 1.0 / fy
    for k in range(cylinders.shape[0]):
        ccx = cylinders[k, 0]
        ccy = cylinders[k, 1]
        zb = cylinders[k, 2]
        zt = cylinders[k, 3]
        rad = cylinders[k, 4]
        _box_to_pixels(R_cam_world, t_cam_world, fx, fy, cx, cy, near, H, W,
                       ccx - rad, ccy - rad, zb, ccx + rad, ccy + rad, zt, box)
        qx = ox - ccx
        qy = oy - ccy
        cq = qx * qx + qy * qy - rad * rad
        for r in range(box[0], box[1] + 1):
            ry = (r - cy) * inv_fy
            for u in range(box[2], box[3] + 1):
                rx = (u - cx) * inv_fx
                dx = R_cam_world[0, 0] * rx + R_cam_world[1, 0] * ry + R_cam_world[2, 0]
                dy = R_cam_world[0, 1] * rx + R_cam_world[1, 1] * ry + R_cam_world[2, 1]
                dz = R_cam_world[0, 2] * rx + R_cam_world[1, 2] * ry + R_cam_world[2, 2]
                best = np.inf
                a = dx * dx + dy * dy
                if a > 1e-18:
                    b = 2.0 * (qx * dx + qy * dy)
                    disc = b * b - 4.0 * a * cq
                    if disc >= 0.0:
                        tt = (-b - math.sqrt(disc)) / (2.0 * a)
                        if tt > near:
                            hz = oz + tt * dz
                            if hz >= zb and hz <= zt:
                                best = tt
                if abs(dz) > 1e-18:
                    for capz in (zb, zt):
                        tt = (capz - oz) / dz
                        if tt > near and tt < best:
                            hx = qx + tt * dx
                            hy = qy + tt * dy
                            if hx * hx + hy * hy <= rad * rad:
                                best = tt
                if best < far and best < depth[r, u]:
                    depth[r, u] = best
                    labels[r, u] = clutter_label
    for k in range(spheres.shape[0]):
        scx = spheres[k, 0]
        scy = spheres[k, 1]
        scz = spheres[k, 2]
        rad = spheres[k, 3]
        _box_to_pixels(R_cam_world, t_cam_world, fx, fy, cx, cy, near, H, W,
                       scx - rad, scy - rad, scz - rad, scx + rad, scy + rad, scz + rad, box)
        qx = ox - scx
        qy = oy - scy
        qz = oz - scz
        cq = qx * qx + qy * qy + qz * qz - rad * rad
        for r in range(box[0], box[1] + 1):
            ry = (r - cy) * inv_fy
            for u in range(box[2], box[3] + 1):
                rx = (u - cx) * inv_fx
                dx = R_cam_world[0, 0] * rx + R_cam_world[1, 0] * ry + R_cam_world[2, 0]
                dy = R_cam_world[0, 1] * rx + R_cam_world[1, 1] * ry + R_cam_world[2, 1]
                dz = R_cam_world[0, 2] * rx + R_cam_world[1, 2] * ry + R_cam_world[2, 2]
                a = dx * dx + dy * dy + dz * dz
                b = 2.0 * (qx * dx + qy * dy + qz * dz)
                disc = b * b - 4.0 * a * cq
                if disc < 0.0:
                    continue
                tt = (-b - math.sqrt(disc)) / (2.0 * a)
                if tt > near and tt < far and tt < depth[r, u]:
                    depth[r, u] = tt
                    labels[r, u] = clutter_label


@njit
def finish_depth(depth, labels):
    """Pixels the z-buffer never reached: depth NaN, label 0 (in place)."""
    H, W = depth.shape
    for r in range(H):
        for u in range(W):
            if not (depth[r, u] < np.inf):
                depth[r, u] = np.nan
                labels[r, u] = 0


@register_warmup
def _warmup() -> None:
    R = np.eye(3)
    t = np.zeros(3)
    verts = np.array([[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [1.0, 1.0, 2.0], [-1.0, 1.0, 2.0]])
    ptr = np.array([0, 4], np.int64)
    normals = np.array([[0.0, 0.0, -1.0]])
    offsets = np.array([2.0])
    lab = np.array([1], np.int32)
    depth = np.full((4, 4), np.inf, np.float32)
    labels = np.zeros((4, 4), np.int32)
    rasterize_polygons(R, t, 2.0, 2.0, 1.5, 1.5, 0.05, 50.0, verts, ptr, normals, offsets, lab, depth, labels)
    raycast_clutter(R, t, 2.0, 2.0, 1.5, 1.5, 0.05, 50.0, np.array([[0.0, 0.0, 1.0, 2.0, 0.5]]),
                    np.array([[0.0, 0.0, 3.0, 0.5]]), np.int32(0), depth, labels)
    finish_depth(depth, labels)
