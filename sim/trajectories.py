"""Camera trajectories through a scene's free space, all as exact ``(N, 4, 4) T_world_cam`` poses.

- ``robot``: a differential-drive robot with the camera at a fixed height: it drives straight between roadmap
  waypoints and turns on the spot, with small smooth pitch and roll (floor unevenness, suspension).
- ``handheld``: a person walking with the camera at chest height: smoothed path, looking around, step bobbing.
- ``random_views``: independent viewpoints for relocalization queries: inside a room, clear of furniture, at a
  random height and orientation, kept only when the camera sees enough structure (several planes, not a wall
  at arm's length).

Camera optical frame: x right, y down, z forward. ``camera_rotation(yaw, pitch, roll)`` builds ``R_world_cam``:
yaw turns the view direction about world z (0 looks along +x), positive pitch looks up, roll turns about the
optical axis.
"""

from __future__ import annotations

import math

import numpy as np

from reloc.camera import Intrinsics
from sim.free_space import Roadmap, is_free, sample_free
from sim.scenes import Scene

__all__ = ["camera_rotation", "pose_from", "robot", "handheld", "random_views", "make_trajectory", "TRAJECTORY_NAMES",
           "TOURS", "gravity_in_camera"]

TRAJECTORY_NAMES = ("robot", "handheld", "random")
# Where robot and hand-held trajectories go: shortest paths to random places ("random"; a short one may never enter
# some room), or every room entered in turn ("rooms", as a mapping run that must leave no room out; a robot's turns on
# the spot take frames the tour's length does not count, so a run too short for a whole round leaves its last rooms
# out: in 3,000 frames the suite's robot enters 4 of the apartment's 6 rooms, the hand-held walk all 6).
TOURS = ("random", "rooms")
_STREAM = {"robot": 11, "handheld": 12, "random": 13}


def camera_rotation(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """``R_world_cam`` (3, 3) of a camera looking along heading ``yaw`` (rad), tilted up by ``pitch``, rolled by
    ``roll`` about its optical axis."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    base = np.array([[sy, 0.0, cy], [-cy, 0.0, sy], [0.0, -1.0, 0.0]])  # columns: right, down, forward
    cp, sp = math.cos(pitch), math.sin(pitch)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return base @ rx @ rz


def pose_from(x: float, y: float, z: float, yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """``T_world_cam`` (4, 4) of a camera at ``(x, y, z)`` with the given yaw, pitch and roll (rad)."""
    T = np.eye(4)
    T[:3, :3] = camera_rotation(yaw, pitch, roll)
    T[:3, 3] = (x, y, z)
    return T


def gravity_in_camera(T_world_cam: np.ndarray) -> np.ndarray:
    """Unit gravity (pointing down, world -z) in the camera frame: ``R_world_cam^T (0, 0, -1)``."""
    return np.asarray(T_world_cam)[:3, :3].T @ np.array([0.0, 0.0, -1.0])


def _rng(seed: int, kind: str) -> np.random.Generator:
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
    return np.random.default_rng(np.random.SeedSequence([int(seed), _STREAM[kind]]))


def _check_n(n_frames: int) -> int:
    if not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise ValueError(f"n_frames: expected a positive integer, got {n_frames!r}")
    return int(n_frames)


def _smooth_signal(rng: np.random.Generator, t: np.ndarray, amplitude: float, f_lo: float = 0.05,
                   f_hi: float = 0.5, n: int = 3) -> np.ndarray:
    """A smooth random signal of peak amplitude <= ``amplitude``: a sum of sinusoids with random frequencies."""
    freqs = rng.uniform(f_lo, f_hi, n)
    phases = rng.uniform(0, 2 * np.pi, n)
    weights = rng.uniform(0.5, 1.0, n)
    weights /= weights.sum()
    return amplitude * (weights[None, :] * np.sin(2 * np.pi * freqs[None, :] * t[:, None] + phases)).sum(axis=1)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def robot(scene: Scene, n_frames: int, seed: int = 0, *, height_m: float = 0.35, speed_mps: float = 0.35,
          turn_rate_deg_s: float = 60.0, max_pitch_deg: float = 2.0, max_roll_deg: float = 1.5,
          pitch_offset_deg: float = 0.0, rate_hz: float = 30.0, clearance_m: float = 0.35,
          tour: str = "random") -> np.ndarray:
    """(N, 4, 4) ``T_world_cam`` of a ground robot driving a tour of the scene at ``rate_hz`` frames per second.

    The camera stays at ``height_m``; pitch (about ``pitch_offset_deg``) and roll wander smoothly within the given
    bounds. The robot drives straight at ``speed_mps`` and turns on the spot at ``turn_rate_deg_s``. ``tour``:
    "random" (shortest paths to random places) or "rooms" (every room entered in turn, see :data:`TOURS`).
    """
    n = _check_n(n_frames)
    rng = _rng(seed, "robot")
    dt = 1.0 / rate_hz
    waypoints = _waypoints(Roadmap(scene, rng, clearance_m), rng, n * dt * speed_mps + 1.0, tour)
    step = speed_mps * dt
    turn = math.radians(turn_rate_deg_s) * dt
    xs, ys, yaws = [], [], []
    pos = waypoints[0].copy()
    d0 = waypoints[1] - waypoints[0]
    yaw = math.atan2(d0[1], d0[0])
    for wp in waypoints[1:]:
        d = wp - pos
        dist = float(np.hypot(*d))
        if dist < 1e-9:
            continue
        heading = math.atan2(d[1], d[0])
        # Turn on the spot, then drive straight.
        while abs(_wrap(heading - yaw)) > 1e-9 and len(xs) < n:
            delta = float(_wrap(heading - yaw))
            yaw += math.copysign(min(turn, abs(delta)), delta)
            xs.append(pos[0]); ys.append(pos[1]); yaws.append(yaw)  # noqa: E702
        k = int(dist // step)
        for i in range(1, k + 1):
            if len(xs) >= n:
                break
            p = pos + d * (i * step / dist)
            xs.append(p[0]); ys.append(p[1]); yaws.append(yaw)  # noqa: E702
        pos = wp.copy()
        if len(xs) >= n:
            break
    while len(xs) < n:  # only when the tour ends exactly on time
        xs.append(pos[0]); ys.append(pos[1]); yaws.append(yaw)  # noqa: E702
    t = np.arange(n) * dt
    pitch = math.radians(pitch_offset_deg) + _smooth_signal(rng, t, math.radians(max_pitch_deg), 0.1, 1.0)
    roll = _smooth_signal(rng, t, math.radians(max_roll_deg), 0.1, 1.0)
    return np.stack([pose_from(xs[i], ys[i], height_m, yaws[i], pitch[i], roll[i]) for i in range(n)])


def _waypoints(roadmap: Roadmap, rng: np.random.Generator, length_m: float, tour: str) -> np.ndarray:
    if tour == "random":
        return roadmap.random_walk(rng, length_m)
    if tour == "rooms":
        return roadmap.room_tour(rng, length_m)
    raise ValueError(f"tour: expected one of {', '.join(TOURS)}, got {tour!r}")


def _moving_average(a: np.ndarray, window: int) -> np.ndarray:
    if window <= 1:
        return a
    pad = window // 2
    padded = np.pad(a, [(pad, pad)] + [(0, 0)] * (a.ndim - 1), mode="edge")
    kernel = np.ones(window) / window
    if a.ndim == 1:
        return np.convolve(padded, kernel, mode="valid")[: len(a)]
    return np.stack([np.convolve(padded[:, j], kernel, mode="valid")[: len(a)] for j in range(a.shape[1])], axis=1)


def handheld(scene: Scene, n_frames: int, seed: int = 0, *, height_m: float = 1.4, speed_mps: float = 0.6,
             look_around_deg: float = 35.0, mean_pitch_deg: float = -12.0, max_pitch_deg: float = 12.0,
             max_roll_deg: float = 5.0, rate_hz: float = 30.0, clearance_m: float = 0.4,
             tour: str = "random") -> np.ndarray:
    """(N, 4, 4) ``T_world_cam`` of a hand-held camera carried on a walk through the scene.

    The walk follows roadmap waypoints (``tour`` as for :func:`robot`), smoothed; the view turns with the walking
    direction plus a slow look-around of up to ``look_around_deg``; pitch wanders about ``mean_pitch_deg``; steps
    make the camera bob by ~2 cm.
    """
    n = _check_n(n_frames)
    rng = _rng(seed, "handheld")
    dt = 1.0 / rate_hz
    waypoints = _waypoints(Roadmap(scene, rng, clearance_m), rng, n * dt * speed_mps + 2.0, tour)
    seg = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    keep = np.concatenate([[True], seg > 1e-9])
    s, waypoints = s[keep], waypoints[keep]
    # Walking speed varies a little; arc length per frame.
    t = np.arange(n) * dt
    speed = speed_mps * (1.0 + _smooth_signal(rng, t, 0.2, 0.05, 0.3))
    arc = np.concatenate([[0.0], np.cumsum(speed[:-1] * dt)])
    arc = np.minimum(arc, s[-1])
    xy = np.column_stack([np.interp(arc, s, waypoints[:, 0]), np.interp(arc, s, waypoints[:, 1])])
    xy = _moving_average(xy, int(0.6 * rate_hz) | 1)
    vel = np.gradient(xy, axis=0) if n > 1 else np.zeros((1, 2))
    heading = np.unwrap(np.arctan2(vel[:, 1], vel[:, 0] + 1e-12))
    heading = _moving_average(heading, int(1.0 * rate_hz) | 1)
    yaw = heading + _smooth_signal(rng, t, math.radians(look_around_deg), 0.03, 0.2)
    pitch = math.radians(mean_pitch_deg) + _smooth_signal(rng, t, math.radians(max_pitch_deg), 0.05, 0.4)
    roll = _smooth_signal(rng, t, math.radians(max_roll_deg), 0.1, 0.6)
    z = height_m + _smooth_signal(rng, t, 0.05, 0.02, 0.1) + 0.02 * np.sin(2 * np.pi * 1.8 * t)
    return np.stack([pose_from(xy[i, 0], xy[i, 1], z[i], yaw[i], pitch[i], roll[i]) for i in range(n)])


def random_views(scene: Scene, n_frames: int, seed: int = 0, *, height_range_m: tuple[float, float] = (0.3, 1.8),
                 pitch_range_deg: tuple[float, float] = (-30.0, 15.0), max_roll_deg: float = 5.0,
                 clearance_m: float = 0.3, min_planes: int = 3, min_plane_fraction: float = 0.03,
                 min_valid_fraction: float = 0.6, min_median_depth_m: float = 1.0, max_depth_m: float = 6.0,
                 max_tries: int = 500, probe: Intrinsics | None = None) -> np.ndarray:
    """(N, 4, 4) independent ``T_world_cam`` query viewpoints in free space that look at enough structure.

    A candidate is rendered at low resolution with ``probe`` (a 80 x 60 Kinect-like camera by default) and kept
    when at least ``min_valid_fraction`` of the pixels see a surface within ``max_depth_m``, at least
    ``min_planes`` planes each cover ``min_plane_fraction`` of the image, and the median depth is at least
    ``min_median_depth_m``.
    """
    from sim.cameras import preset
    from sim.render import render

    n = _check_n(n_frames)
    rng = _rng(seed, "random")
    probe = probe or preset("kinect").scaled(80, 60)
    out = []
    tries = 0
    while len(out) < n:
        xy = sample_free(scene, rng, 1, clearance_m)[0]
        z = rng.uniform(*height_range_m)
        yaw = rng.uniform(-np.pi, np.pi)
        pitch = math.radians(rng.uniform(*pitch_range_deg))
        roll = math.radians(rng.uniform(-max_roll_deg, max_roll_deg))
        tries += 1
        if tries > max_tries * n:
            raise ValueError(f"scene {scene.name!r}: found only {len(out)} of {n} views with enough structure "
                             f"after {tries - 1} tries")
        T = pose_from(xy[0], xy[1], z, yaw, pitch, roll)
        depth, labels = render(scene, probe, T)
        ok = np.isfinite(depth) & (depth <= max_depth_m)
        if ok.mean() < min_valid_fraction or np.median(depth[ok]) < min_median_depth_m:
            continue
        ids, counts = np.unique(labels[ok & (labels > 0)], return_counts=True)
        if int((counts >= min_plane_fraction * labels.size).sum()) < min_planes:
            continue
        out.append(T)
    return np.stack(out)


def make_trajectory(kind: str, scene: Scene, n_frames: int, seed: int = 0, **kwargs) -> np.ndarray:
    """``robot``, ``handheld`` or ``random`` (random_views) by name."""
    if kind == "robot":
        return robot(scene, n_frames, seed, **kwargs)
    if kind == "handheld":
        return handheld(scene, n_frames, seed, **kwargs)
    if kind in ("random", "random_views"):
        return random_views(scene, n_frames, seed, **kwargs)
    raise ValueError(f"trajectory: expected one of {', '.join(TRAJECTORY_NAMES)}, got {kind!r}")


def check_poses_free(scene: Scene, T_world_cam: np.ndarray, clearance_m: float = 0.2) -> np.ndarray:
    """(N,) bool: each camera centre is in free space with ``clearance_m``."""
    return is_free(scene, np.asarray(T_world_cam)[:, :2, 3], clearance_m)
