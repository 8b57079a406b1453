"""Small helpers shared by several test modules (not a test module itself)."""

from __future__ import annotations

import time
from pathlib import Path


def wait_until(predicate, timeout_s: float = 10.0, period_s: float = 0.01) -> bool:
    """Poll ``predicate`` until it is true or ``timeout_s`` has passed; its last value."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(period_s)
    return predicate()


def write_office_sequence(out: Path, n_frames: int) -> Path:
    """A small simulated office sequence on disk (handheld, Kinect noise, 160x120, seed 5) for command tests."""
    from sim import simulate_frames
    from sim.scenes import make_scene
    from sim.writer import write_sequence

    scene = make_scene("office")
    frames = simulate_frames(scene, "handheld", n_frames, noise="kinect", camera="kinect", seed=5, width=160,
                             height=120)
    write_sequence(frames, scene, out)
    return out
