"""A simulated camera riding on the simulated firmware's robot, so `reloc run` and `reloc firmware-sim` in two
processes see one world.

``reloc firmware-sim --trajectory robot --scene S`` drives its base along a simulator trajectory as a function of the
MCU's clock. :class:`FirmwareSyncedSimSource` renders each frame from that same base pose at the MCU time of the
moment it is taken (``T_world_cam = T_map_base(t_mcu) @ T_base_cam``), using the MCU clock as the host bridge has
learnt it from the heartbeats. The firmware's checks of the poses it receives are then meaningful end to end.
"""

from __future__ import annotations

import time
from typing import Callable, Iterator

import numpy as np

from reloc.camera import DepthFrame, Intrinsics

from drivers.source import FrameSource, Pacer

__all__ = ["FirmwareSyncedSimSource"]


class FirmwareSyncedSimSource(FrameSource):
    """Frames of ``scene`` seen from a base on ``path`` (``path.T_map_base(t_s)``, MCU time) through ``T_base_cam``.

    - ``mcu_time_ns(host_ns)``: the MCU clock at a host time, or None while it is unknown (no frames until then).
    - ``intrinsics``, ``noise``: the simulated camera; ``rate_hz``: frames per second (paced in real time).
    Frames are stamped with the host clock (``time.monotonic_ns``) and carry the rendered pose as ground truth.
    """

    def __init__(self, scene, path, T_base_cam: np.ndarray, mcu_time_ns: Callable[[int], int | None], *,
                 intrinsics: Intrinsics, noise: str = "stereo", rate_hz: float = 30.0, seed: int = 0) -> None:
        super().__init__()
        from sim.noise import make_noise

        if not rate_hz > 0:
            raise ValueError(f"rate_hz: expected > 0, got {rate_hz!r}")
        self.scene, self.path = scene, path
        self.T_base_cam = np.asarray(T_base_cam, dtype=np.float64)
        self.mcu_time_ns = mcu_time_ns
        self._intrinsics = intrinsics
        self.noise = make_noise(noise)
        self._rate = float(rate_hz)
        self.seed = int(seed)
        self.name = f"sim-on-firmware:{scene.name}"

    @classmethod
    def like_firmware_sim(cls, scene_name: str, frames: int, T_base_cam, mcu_time_ns, *, camera: str = "oak-d",
                          trajectory: str = "robot", rate_hz: float = 30.0, seed: int = 0, **kwargs):
        """On the path ``reloc firmware-sim --trajectory T --scene S --frames N --rate-hz R --trajectory-seed K``
        drives."""
        from firmware_bridge.mcu_sim import SampledPath
        from sim.cameras import resolve_intrinsics
        from sim.scenes import make_scene
        from sim.trajectories import make_trajectory

        scene = make_scene(scene_name, seed=seed)
        poses = make_trajectory(trajectory, scene, frames, seed, rate_hz=rate_hz)
        path = SampledPath.from_T_world_cam(poses, rate_hz, T_base_cam)
        return cls(scene, path, T_base_cam, mcu_time_ns, intrinsics=resolve_intrinsics(camera), rate_hz=rate_hz,
                   seed=seed, **kwargs)

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intrinsics

    def noise_law(self) -> tuple[str, float] | None:
        return self.noise.extraction_law(self._intrinsics.fx)

    @property
    def rate_hz(self) -> float:
        return self._rate

    def _frames(self) -> Iterator[DepthFrame]:
        from sim.render import render
        from sim.trajectories import gravity_in_camera

        pacer = Pacer(self._rate)
        seq = 0
        while not self.closed:
            pacer.wait(0)
            now = time.monotonic_ns()
            t_mcu = self.mcu_time_ns(now)
            if t_mcu is None:  # the firmware's clock is not known yet: nothing to render from
                continue
            T = self.path.T_map_base(t_mcu * 1e-9) @ self.T_base_cam
            depth, labels = render(self.scene, self._intrinsics, T)
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, 41, seq]))
            depth, labels = self.noise.apply(depth, labels, self._intrinsics, rng)
            yield DepthFrame(depth, self._intrinsics, now, seq, T_world_cam=T, gravity_cam=gravity_in_camera(T),
                             pose_source="groundtruth", labels=labels)
            seq += 1
