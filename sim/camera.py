"""The simulated depth camera: a scene, intrinsics, a noise model and a trajectory, yielding one DepthFrame at a
time (stamps at ``rate_hz``), with ground truth attached (pose, gravity, plane labels).

Frame ``i`` depends only on the scene, the pose, the seed and ``i`` (each frame's noise has its own random stream),
so iterating, indexing and :func:`sim.simulate_frames` all give identical frames.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from reloc.camera import DepthFrame, Intrinsics
from reloc.transforms import check_transform
from sim.cameras import RATE_RANGE_HZ
from sim.noise import NoiseModel, make_noise
from sim.render import render
from sim.scenes import Scene
from sim.trajectories import gravity_in_camera

__all__ = ["SimCamera", "people_tracks"]

_NOISE_STREAM = 21
_PEOPLE_STREAM = 22


def people_tracks(scene: Scene, n_frames: int, n_people: int, seed: int = 0, rate_hz: float = 30.0,
                  speed_mps: float = 1.0) -> np.ndarray:
    """(n_frames, n_people, 5) cylinders ``[x, y, 0, 1.75, 0.25]`` of people walking through the free space."""
    from sim.free_space import Roadmap

    out = np.zeros((n_frames, n_people, 5))
    if n_people == 0:
        return out
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), _PEOPLE_STREAM]))
    roadmap = Roadmap(scene, rng, clearance_m=0.3)
    dt = 1.0 / rate_hz
    for k in range(n_people):
        wps = roadmap.random_walk(rng, n_frames * dt * speed_mps + 1.0)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(wps, axis=0), axis=1))])
        arc = np.minimum(np.arange(n_frames) * dt * speed_mps, s[-1])
        out[:, k, 0] = np.interp(arc, s, wps[:, 0])
        out[:, k, 1] = np.interp(arc, s, wps[:, 1])
        out[:, k, 3] = rng.uniform(1.6, 1.9)
        out[:, k, 4] = rng.uniform(0.2, 0.28)
    return out


class SimCamera:
    """Iterable of simulated :class:`~reloc.camera.DepthFrame` along ``trajectory_poses`` (N, 4, 4 T_world_cam).

    ``len()`` and indexing work too. Frames carry ``T_world_cam`` (pose_source "groundtruth"), ``gravity_cam`` and
    ``labels`` (plane ids, 0 for none). ``people`` moving cylinders walk through the scene.
    """

    def __init__(self, scene: Scene, intrinsics: Intrinsics, noise: "str | NoiseModel", trajectory_poses: np.ndarray,
                 seed: int = 0, rate_hz: float = 30.0, people: int = 0, start_ns: int = 0) -> None:
        if not isinstance(scene, Scene):
            raise ValueError(f"scene: expected a sim.scenes.Scene, got {type(scene).__name__}")
        if not isinstance(intrinsics, Intrinsics):
            raise ValueError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
        poses = np.asarray(trajectory_poses, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or poses.shape[0] == 0:
            raise ValueError(f"trajectory_poses: expected shape (N, 4, 4) with N >= 1, got {poses.shape}")
        for i in range(len(poses)):
            check_transform(poses[i], f"trajectory_poses[{i}]")
        lo, hi = RATE_RANGE_HZ
        if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float, np.number)) or not lo <= rate_hz <= hi:
            raise ValueError(f"rate_hz: expected a frame rate of {lo:g} to {hi:g} Hz, got {rate_hz!r}")
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
        if not isinstance(people, (int, np.integer)) or people < 0:
            raise ValueError(f"people: expected a non-negative integer, got {people!r}")
        self.scene = scene
        self.intrinsics = intrinsics
        self.noise = make_noise(noise)
        self.poses = poses
        self.seed = int(seed)
        self.rate_hz = float(rate_hz)
        self.start_ns = int(start_ns)
        self.people = people_tracks(scene, len(poses), int(people), self.seed, self.rate_hz)

    def __len__(self) -> int:
        return int(self.poses.shape[0])

    def stamp_ns(self, i: int) -> int:
        return self.start_ns + int(round(i * 1e9 / self.rate_hz))

    def render_truth(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free ``(depth_m, labels)`` of frame ``i``."""
        return render(self.scene, self.intrinsics, self.poses[i], extra_cylinders=self.people[i])

    def __getitem__(self, i: int) -> DepthFrame:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for {n} frames")
        i = i % n
        depth, labels = self.render_truth(i)
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, _NOISE_STREAM, i]))
        depth, labels = self.noise.apply(depth, labels, self.intrinsics, rng)
        T = self.poses[i]
        return DepthFrame(
            depth_m=depth, intrinsics=self.intrinsics, stamp_ns=self.stamp_ns(i), seq=i, T_world_cam=T.copy(),
            gravity_cam=gravity_in_camera(T), pose_source="groundtruth", labels=labels,
        )

    def __iter__(self) -> Iterator[DepthFrame]:
        for i in range(len(self)):
            yield self[i]
