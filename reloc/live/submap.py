"""A sliding window of recent frames' planes, fused into one submap in the newest camera frame with odometry."""

from __future__ import annotations

from collections import deque

import numpy as np

from reloc.planeset import PlaneSet
from reloc.transforms import invert

__all__ = ["SubmapWindow", "concat_plane_sets"]


def concat_plane_sets(sets: list[PlaneSet], frame: str, gravity: np.ndarray | None,
                      gravity_tolerance_rad: float = 0.0) -> PlaneSet:
    """One plane set holding the rows of ``sets`` (all in the same frame ``frame``), samples included."""
    sets = [s for s in sets if len(s)]
    g = dict(frame=frame, gravity=gravity, gravity_tolerance_rad=gravity_tolerance_rad)
    if not sets:
        return PlaneSet.empty(**g)
    if len(sets) == 1:
        s = sets[0]
        return PlaneSet(**{k: getattr(s, k) for k in _FIELDS}, sample_points=s.sample_points,
                        sample_ptr=s.sample_ptr, **g)
    cols = {k: np.concatenate([getattr(s, k) for s in sets]) for k in _FIELDS}
    sizes = np.concatenate([np.diff(s.sample_ptr) for s in sets])
    return PlaneSet(**cols, sample_points=np.concatenate([s.sample_points for s in sets]),
                    sample_ptr=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64), **g)


_FIELDS = ("normals", "offsets", "centroids", "counts", "radii", "areas", "covariances", "sums", "scatters")


class SubmapWindow:
    """The planes of the last ``window_frames`` frames (``max_frames`` kept when the window may grow) with their
    odometry poses ``T_odom_cam``.

    ``build()`` moves every frame's planes into the newest camera frame (``T_cam_new_cam_i = inv(T_odom_cam_new) @
    T_odom_cam_i``), so the submap is expressed where the relocalized pose will hold. A frame without odometry
    restarts the window (its planes cannot be related to the others), as does :meth:`reset` (after an odometry jump
    or reset). With ``fuse`` (``fuse(plane_sets, T_odom_cams) -> PlaneSet``, e.g. :func:`reloc.mapping.build_submap`)
    planes seen in several frames are fused into one; without it they are stacked as separate rows (the matcher's
    verification counts area, and duplicates of one surface agree with each other).
    """

    def __init__(self, window_frames: int = 1, fuse=None, *, max_frames: int = 0, grow=None):
        if not isinstance(window_frames, int) or window_frames < 1:
            raise ValueError(f"window_frames: expected a positive integer, got {window_frames!r}")
        if fuse is not None and not callable(fuse):
            raise ValueError(f"fuse: expected a callable (plane_sets, T_odom_cams) -> PlaneSet, got {fuse!r}")
        if not isinstance(max_frames, int) or (max_frames and max_frames < window_frames) or max_frames < 0:
            raise ValueError(f"max_frames: expected 0 (the window does not grow) or at least window_frames "
                             f"({window_frames}), got {max_frames!r}")
        if max_frames > window_frames and not callable(grow):
            raise ValueError("grow: expected a callable (fetch, first, most) -> (PlaneSet, frames) for a window "
                             f"that grows to {max_frames} frames, got {grow!r}")
        self.window_frames = window_frames
        self.max_frames = max(window_frames, max_frames)
        self.fuse = fuse
        self.grow = grow if self.max_frames > window_frames else None
        self.last_frames = 0  # frames in the submap :meth:`build` made last
        self._items: deque[tuple[PlaneSet, np.ndarray | None, int]] = deque(maxlen=self.max_frames)

    def push(self, planes_cam: PlaneSet, T_odom_cam: np.ndarray | None, seq: int) -> None:
        """Add a frame's planes (camera frame) and its odometry pose (None when unknown)."""
        if T_odom_cam is None or (self._items and self._items[-1][1] is None):
            self._items.clear()
        self._items.append((planes_cam, None if T_odom_cam is None else np.asarray(T_odom_cam, float), int(seq)))

    def reset(self) -> None:
        self._items.clear()

    def __len__(self) -> int:
        return len(self._items)

    @property
    def seqs(self) -> list[int]:
        return [s for _, _, s in self._items]

    def build(self) -> PlaneSet:
        """The submap in the newest frame's camera frame (frame name "cam"), gravity from the newest frame: of the
        last ``window_frames`` frames, or, with ``grow``, of as many of the last ``max_frames`` as it takes to pin a
        pose (``grow(fetch, first, most)``, e.g. :meth:`reloc.live.factory.SubmapFuser.grow`)."""
        items = list(self._items)
        if not items:
            self.last_frames = 0
            return PlaneSet.empty(frame="cam")
        if self.grow is not None and len(items) > 1:
            def fetch(k: int):
                return [p for p, _, _ in items[-k:]], [T for _, T, _ in items[-k:]]

            submap, self.last_frames = self.grow(fetch, min(self.window_frames, len(items)), len(items))
            return submap
        items = items[-self.window_frames:]
        self.last_frames = len(items)
        newest, T_new, _ = items[-1]
        if len(items) == 1:
            return newest
        if self.fuse is not None:
            return self.fuse([p for p, _, _ in items], [T for _, T, _ in items])
        T_new_odom = invert(T_new)
        moved = [p if i == len(items) - 1 else p.transformed(T_new_odom @ T, "cam")
                 for i, (p, T, _) in enumerate(items)]
        return concat_plane_sets(moved, "cam", newest.gravity, newest.gravity_tolerance_rad)
