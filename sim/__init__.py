"""Simulated depth camera: planar indoor scenes, sensor noise, trajectories, exact ground truth.

One-shot: ``simulate_frames(scene="living_room", trajectory="robot", n_frames=10, noise="kinect", camera="kinect",
seed=0)``. The steps are public: :mod:`sim.scenes` (``make_scene``), :mod:`sim.cameras` (``preset``),
:mod:`sim.noise` (``make_noise``), :mod:`sim.trajectories`, :mod:`sim.render` (``render``), :mod:`sim.camera`
(``SimCamera``), :mod:`sim.ground_truth` (``visible_planes``) and :mod:`sim.writer` (``write_sequence``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["simulate_frames", "make_camera", "KERNEL_MODULES"]

# The simulator's numba kernels, for a warm-up to compile before anything is timed (noise is imported only when a
# frame is first made noisy, so a warm-up of sim.render alone left its compilation inside the first timed phase).
KERNEL_MODULES = ("sim._render_kernels", "sim._noise_kernels")


def make_camera(scene="living_room", trajectory="robot", n_frames: int = 10, noise="kinect", camera="kinect",
                seed: int = 0, *, scene_seed: int = 0, people: int = 0, rate_hz: float = 30.0,
                width: int | None = None, height: int | None = None, trajectory_kwargs: dict | None = None):
    """A :class:`sim.camera.SimCamera` built from names (or objects): see :func:`simulate_frames`."""
    from sim.camera import SimCamera
    from sim.cameras import resolve_intrinsics
    from sim.scenes import Scene, make_scene
    from sim.trajectories import make_trajectory

    sc = scene if isinstance(scene, Scene) else make_scene(scene, scene_seed)
    intr = resolve_intrinsics(camera, width, height)
    if isinstance(trajectory, str):
        poses = make_trajectory(trajectory, sc, n_frames, seed, **(trajectory_kwargs or {}))
    else:
        poses = np.asarray(trajectory, dtype=np.float64)
    return SimCamera(sc, intr, noise, poses, seed=seed, rate_hz=rate_hz, people=people)


def simulate_frames(scene="living_room", trajectory="robot", n_frames: int = 10, noise="kinect", camera="kinect",
                    seed: int = 0, *, scene_seed: int = 0, people: int = 0, rate_hz: float = 30.0,
                    width: int | None = None, height: int | None = None,
                    trajectory_kwargs: dict | None = None) -> list:
    """Render ``n_frames`` noisy depth frames with ground truth (list of :class:`reloc.camera.DepthFrame`).

    - ``scene``: a name for :func:`sim.scenes.make_scene` (built with ``scene_seed``) or a Scene.
    - ``trajectory``: "robot", "handheld", "random", or an (N, 4, 4) array of ``T_world_cam`` (then
      ``n_frames`` is ignored).
    - ``noise``: "none", "stereo", "kinect", "tof" or a NoiseModel. ``camera``: a preset name or an Intrinsics,
      resampled to ``width x height`` when given.
    - ``seed`` drives the trajectory and the noise; the scene's world frame does not depend on it.
    Frames carry labels, ``T_world_cam`` and ``gravity_cam``; stamps advance at ``rate_hz``.
    """
    return list(make_camera(scene, trajectory, n_frames, noise, camera, seed, scene_seed=scene_seed, people=people,
                            rate_hz=rate_hz, width=width, height=height, trajectory_kwargs=trajectory_kwargs))
