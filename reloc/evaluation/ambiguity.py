"""Which positive queries have no unique answer: views that look the same from another place of the scene.

Three scenes repeat themselves by construction: ``meeting_rooms`` (identical rooms side by side, one room pitch
apart along x), ``symmetric_room`` (four-fold symmetric about its centre) and ``corridor`` (doors every 6 m on
either side, the two sides 3 m out of step: along it by 6 m, and half a turn about a vertical axis on its centre
line at x = 1.5, 4.5, 7.5, ... m, which takes each side's doors to the other's). For a query pose ``T`` and each
symmetry ``S`` of the scene, the depth image rendered from ``S @ T`` is compared with the one from ``T``, both cut
at the sensor's range ``max_range_m``; when they agree (within ``tol_m`` on at least ``min_fraction`` of the pixels,
missing pixels agreeing with missing pixels) the two places look alike to any depth-only method, but for the few
per cent of pixels that may differ, and the query is labelled ambiguous (a matcher that answers it has guessed, or
read those few pixels; either counts as a false positive).
The label comes from the scene's geometry alone, never from the matcher under test.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["scene_symmetries", "is_ambiguous"]


def _rotation_about_z(cx: float, cy: float, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = np.array([cx, cy]) - T[:2, :2] @ np.array([cx, cy])
    return T


def scene_symmetries(scene) -> list[np.ndarray]:
    """Candidate symmetries ``S`` (4x4, world to world) of a simulated scene (the scene or its name); empty for
    scenes without any."""
    from sim.scenes import WALL_T

    name = scene if isinstance(scene, str) else scene.name
    if name == "meeting_rooms":
        pitch = 5.0 + WALL_T
        out = []
        for k in (-3, -2, -1, 1, 2, 3):
            T = np.eye(4)
            T[0, 3] = k * pitch
            out.append(T)
        return out
    if name == "symmetric_room":
        return [_rotation_about_z(3.0, 3.0, k * math.pi / 2) for k in (1, 2, 3)]
    if name == "corridor":
        out = []
        for k in (-4, -3, -2, -1, 1, 2, 3, 4):
            T = np.eye(4)
            T[0, 3] = 6.0 * k
            out.append(T)
        # Doors at x = 3, 9, ..., 27 on the y = 2 side and 6, 12, ..., 24 on the y = 0 side (sim.scenes._corridor):
        # half a turn about (x0, 1) with x0 = 1.5, 4.5, ..., 28.5 maps each side's doors onto the other's (the ends
        # and the cabinets differ, which the renders below tell).
        out += [_rotation_about_z(4.5 + 3.0 * m, 1.0, math.pi) for m in range(-1, 9)]
        return out
    return []


def is_ambiguous(scene, T_world_cams, *, max_range_m: float = 5.0, tol_m: float = 0.02, min_fraction: float = 0.98,
                 probe=None, symmetries=None) -> bool:
    """True when every pose of ``T_world_cams`` ((N, 4, 4) or (4, 4)) has a symmetric twin ``S @ T`` (one ``S`` for
    all, from ``symmetries`` or else :func:`scene_symmetries`) whose rendered depth image is the same."""
    from sim.cameras import preset
    from sim.render import render

    poses = np.asarray(T_world_cams, dtype=np.float64).reshape(-1, 4, 4)
    probe = probe or preset("kinect").scaled(80, 60)
    for S in scene_symmetries(scene) if symmetries is None else symmetries:
        same = True
        for T in poses:
            a, _ = render(scene, probe, T)
            b, _ = render(scene, probe, S @ T)
            a[a > max_range_m] = np.nan
            b[b > max_range_m] = np.nan
            na, nb = ~np.isfinite(a), ~np.isfinite(b)
            agree = (na & nb) | (~na & ~nb & (np.abs(np.nan_to_num(a) - np.nan_to_num(b)) <= tol_m))
            if agree.mean() < min_fraction:
                same = False
                break
        if same:
            return True
    return False
