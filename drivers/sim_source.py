"""The simulated camera as a frame source: ``sim.make_camera`` frames, paced in real time or as fast as taken.

Defaults match the robot's camera: an OAK-D class stereo sensor (640x400, stereo noise) on the robot trajectory
through the living room, 30 Hz. Frames carry the simulator's ground truth (``T_world_cam`` with pose_source
"groundtruth", ``gravity_cam``, ``labels``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Iterator

from reloc.camera import DepthFrame, Intrinsics

from drivers.source import FrameSource, Pacer, check_flag, parse_rate

__all__ = ["SimSource"]


class SimSource(FrameSource):
    """Simulated depth frames (see :func:`sim.make_camera` for scene, trajectory, noise, camera, seed, people).

    - ``n_frames``: length of the trajectory; with ``loop=True`` it repeats (stamps and ``seq`` keep increasing).
    - ``rate``: "recorded" (real time at ``rate_hz``), "fast", or a fixed rate in Hz.
    """

    def __init__(self, scene: str = "living_room", *, trajectory: str = "robot", n_frames: int = 300,
                 noise: str = "stereo", camera: "str | Intrinsics" = "oak-d", seed: int = 0, scene_seed: int = 0,
                 people: int = 0, rate_hz: float = 30.0, rate: "str | float" = "recorded", loop: bool = False,
                 width: int | None = None, height: int | None = None) -> None:
        super().__init__()
        import sim

        if not isinstance(n_frames, int) or n_frames < 1:
            raise ValueError(f"n_frames: expected a positive integer, got {n_frames!r}")
        self.rate = parse_rate(rate)
        self.camera = sim.make_camera(scene, trajectory, n_frames, noise, camera, seed, scene_seed=scene_seed,
                                      people=people, rate_hz=rate_hz, width=width, height=height)
        self.scene = self.camera.scene
        self.loop = check_flag("loop", loop)
        self.name = f"sim:{self.scene.name}"
        self._info = {"scene": self.scene.name, "scene_seed": scene_seed, "trajectory": trajectory,
                      "n_frames": n_frames, "noise": noise, "seed": seed, "people": people}

    @property
    def intrinsics(self) -> Intrinsics:
        return self.camera.intrinsics

    def noise_law(self) -> tuple[str, float] | None:
        return self.camera.noise.extraction_law(self.camera.intrinsics.fx)

    @property
    def rate_hz(self) -> float:
        return self.rate if isinstance(self.rate, float) else self.camera.rate_hz

    def __len__(self) -> int:
        return len(self.camera)

    def _frames(self) -> Iterator[DepthFrame]:
        pacer = Pacer(self.rate)
        n = len(self.camera)
        period = int(round(1e9 / self.camera.rate_hz))
        k = 0
        while not self.closed:
            for i in range(n):
                if self.closed:
                    return
                frame = self.camera[i]
                if k:
                    frame = replace(frame, stamp_ns=frame.stamp_ns + k * n * period, seq=frame.seq + k * n)
                pacer.wait(frame.stamp_ns)
                yield frame
            if not self.loop:
                return
            k += 1

    def info(self) -> dict:
        return {**super().info(), **self._info}
