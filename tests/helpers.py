"""Small helpers shared by several test modules (not a test module itself)."""

from __future__ import annotations

import time
from pathlib import Path

# Every module whose kernels have warm-ups (``reloc._numba.register_warmup``).
KERNEL_MODULES = ("reloc.extraction.pipeline", "reloc.matching._kernels", "reloc.mapping._kernels",
                  "sim._noise_kernels", "sim._render_kernels")


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


def corridor_walk(n: int):
    """A 2 m wide, 40 m long corridor with one cabinet (1.0 x 0.8 x 1.5 m) by its wall at x = 6, and a camera
    walking along it past the cabinet, looking ahead and to the left: the first frames see the cabinet, the last
    only floor, ceiling and the two walls."""
    from reloc.evaluation.synthetic import Rect, box, look_at, view_planes

    length = 40.0
    rects = [Rect((length / 2, 1.0, 0.0), (0, 0, 1), (1, 0, 0), length / 2, 1.0),
             Rect((length / 2, 1.0, 2.5), (0, 0, -1), (1, 0, 0), length / 2, 1.0),
             Rect((length / 2, 0.0, 1.25), (0, 1, 0), (-1, 0, 0), length / 2, 1.25),
             Rect((length / 2, 2.0, 1.25), (0, -1, 0), (1, 0, 0), length / 2, 1.25)]
    rects += box((6.0, 1.6), (1.0, 0.8, 1.5))
    Ts = [look_at((2.0 + 0.25 * k, 1.0, 1.2), (6.0 + 0.25 * k, 1.6, 1.0)) for k in range(n)]
    return Ts, [view_planes(rects, T) for T in Ts]
