"""Plain parameters of the live loop, read from the config at the edge (CLI, factories)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from reloc.live.tracking import OdometryDrift
from reloc.transforms import check_transform

__all__ = ["LiveParams"]


@dataclass(frozen=True)
class LiveParams:
    """Everything :class:`reloc.live.loop.LiveLoop` needs besides its components (units in the names).

    - ``queue_frames``: capture queue length; when full the oldest frame is dropped and counted.
    - ``window_frames``: frames fused into a submap with their odometry (1 = single-frame submaps);
      ``max_window_frames``: how far a submap that cannot pin a pose may grow back in time (0 = not at all).
    - ``reloc_period_s``: periodic verification; ``search_period_s``: retry period while lost.
    - ``lost_jump_m`` / ``lost_jump_rad``: an odometry step larger than this between frames means lost.
    - ``lost_min_explained`` / ``lost_frames``: the tracking check (see :func:`reloc.live.tracking.explained_fraction`)
      failing this many frames in a row means lost; ``check_max_angle_rad`` / ``check_max_offset_m`` are its
      plane-to-plane tolerances.
    - ``status_period_s``: status line period; ``stall_s``: a gap in the frame stream this long is a stall.
    - ``reconnect_backoff_s``: waits between reconnect attempts of a lost source (the last repeats).
    - ``T_base_cam``: (4, 4) camera mounting on the robot base (for odometry in and poses out over serial).
    - ``odometry_drift``: how far the odometry may drift from a relocalized pose, for the covariance of the poses
      tracked from it (:class:`reloc.live.tracking.OdometryDrift`).
    """

    queue_frames: int = 4
    window_frames: int = 1
    max_window_frames: int = 0
    reloc_period_s: float = 5.0
    search_period_s: float = 0.25
    lost_jump_m: float = 0.5
    lost_jump_rad: float = math.radians(30.0)
    lost_min_explained: float = 0.3
    lost_frames: int = 5
    check_max_angle_rad: float = math.radians(5.0)
    check_max_offset_m: float = 0.08
    status_period_s: float = 1.0
    stall_s: float = 1.0
    reconnect_backoff_s: tuple = (0.1, 0.2, 0.5, 1.0, 2.0)
    T_base_cam: np.ndarray = field(default_factory=lambda: np.eye(4))
    odometry_drift: OdometryDrift = field(default_factory=OdometryDrift)

    def __post_init__(self) -> None:
        for name in ("queue_frames", "window_frames", "lost_frames"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name}: expected a positive integer, got {v!r}")
        if not isinstance(self.max_window_frames, (int, np.integer)) or self.max_window_frames < 0 or (
                0 < self.max_window_frames < self.window_frames):
            raise ValueError(f"max_window_frames: expected 0 or at least window_frames ({self.window_frames}), got "
                             f"{self.max_window_frames!r}")
        for name in ("reloc_period_s", "search_period_s", "lost_jump_m", "lost_jump_rad", "check_max_angle_rad",
                     "check_max_offset_m", "status_period_s", "stall_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"{name}: expected a positive number, got {v!r}")
        if not 0.0 <= self.lost_min_explained <= 1.0:
            raise ValueError(f"lost_min_explained: expected a fraction in [0, 1], got {self.lost_min_explained!r}")
        backoff = tuple(float(x) for x in self.reconnect_backoff_s)
        if not backoff or min(backoff) < 0:
            raise ValueError(f"reconnect_backoff_s: expected non-negative waits, got {self.reconnect_backoff_s!r}")
        object.__setattr__(self, "reconnect_backoff_s", backoff)
        object.__setattr__(self, "T_base_cam", check_transform(np.asarray(self.T_base_cam, float), "T_base_cam"))

    @classmethod
    def from_config(cls, cfg, **overrides) -> "LiveParams":
        """From a :class:`reloc.config.Config` (sections live, mapping, evaluation, camera); keywords win."""
        live = cfg.live
        kwargs = dict(
            queue_frames=live.queue_frames,
            window_frames=cfg.mapping.submap_window_frames,
            max_window_frames=cfg.mapping.submap_max_window_frames,
            reloc_period_s=live.reloc_period_s,
            search_period_s=live.search_period_s,
            lost_jump_m=live.lost_jump_m,
            lost_jump_rad=math.radians(live.lost_jump_deg),
            lost_min_explained=live.lost_min_explained,
            lost_frames=live.lost_frames,
            check_max_angle_rad=math.radians(cfg.evaluation.match_max_angle_deg),
            check_max_offset_m=cfg.evaluation.match_max_offset_m,
            status_period_s=live.status_period_s,
            stall_s=live.stall_s,
            reconnect_backoff_s=tuple(live.reconnect_backoff_s),
            T_base_cam=np.array(cfg.camera.T_base_cam, dtype=np.float64).reshape(4, 4),
            odometry_drift=OdometryDrift(
                m_per_m=live.odometry_drift_m_per_m, rad_per_m=math.radians(live.odometry_heading_drift_deg_per_m),
                rad_per_rad=live.odometry_heading_drift_per_turn,
                rad_per_s=math.radians(live.odometry_heading_drift_deg_per_s),
            ),
        )
        kwargs.update(overrides)
        return cls(**kwargs)
