"""Replay of any sequence the reader takes (TUM RGB-D, 7-Scenes, pose folders, a single PNG) as a frame source.

Frames keep the file's stamps, poses, gravity and labels, so what is replayed can be evaluated against its ground
truth. With ``loop=True`` the sequence repeats, each pass shifted by the sequence's span plus one frame period so
that stamps keep increasing (and ``seq`` keeps counting).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np

from reloc.camera import DepthFrame, Intrinsics

from drivers.readers import Sequence, open_sequence, read_noise_law
from drivers.source import FrameSource, Pacer, check_flag, parse_rate

__all__ = ["ReplaySource"]


class ReplaySource(FrameSource):
    """Frames of a sequence on disk (or an opened :class:`~drivers.readers.Sequence`), paced.

    - ``rate``: "recorded" (at the file stamps, times ``speed``), "fast" (as fast as they are taken) or a fixed
      rate in Hz.
    - ``start``/``stop``/``step``: the slice of the sequence to play. ``loop``: repeat forever.
    - ``max_dt_s``, ``poses``: passed to :func:`drivers.readers.open_sequence`.
    """

    def __init__(self, path: "str | os.PathLike | Sequence", *, rate: "str | float" = "recorded", speed: float = 1.0,
                 loop: bool = False, start: int = 0, stop: int | None = None, step: int = 1,
                 max_dt_s: float = 0.02, poses: str = "auto") -> None:
        super().__init__()
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 1:
            raise ValueError(f"step: expected a positive integer (frames are played forward in time), got {step!r}")
        seq = path if isinstance(path, Sequence) else open_sequence(path, max_dt_s=max_dt_s, poses=poses)
        self.sequence = seq[start:stop:step]
        if len(self.sequence) == 0:
            raise ValueError(f"start/stop/step: the slice [{start}:{stop}:{step}] of {seq.path} holds no frame")
        self.name = f"replay:{Path(seq.path)}"
        self.rate = parse_rate(rate)
        self.speed = speed
        self.loop = check_flag("loop", loop)
        Pacer(self.rate, speed=speed)  # validate now, not at the first frame

    @property
    def intrinsics(self) -> Intrinsics:
        return self.sequence.intrinsics

    def noise_law(self) -> tuple[str, float] | None:
        """The law the recording stored (``recording.json`` of ``reloc record``, ``sim.json`` of ``reloc sim``)."""
        return read_noise_law(self.sequence.path)

    @property
    def rate_hz(self) -> float | None:
        if isinstance(self.rate, float):
            return self.rate
        r = self.sequence.rate_hz
        return None if r is None else r * (self.speed if self.rate == "recorded" else 1.0)

    def __len__(self) -> int:
        """Frames per pass."""
        return len(self.sequence)

    def _frames(self) -> Iterator[DepthFrame]:
        seq = self.sequence
        pacer = Pacer(self.rate, speed=self.speed)
        n = len(seq)
        period = int(round(1e9 / seq.rate_hz)) if seq.rate_hz else 33_333_333
        span = int(seq.stamps_ns[-1] - seq.stamps_ns[0]) + period
        seq_step = int(seq.seqs[1] - seq.seqs[0]) if n > 1 else 1  # a pass goes on as the slice's step does
        seq_span = int(seq.seqs[-1] - seq.seqs[0]) + seq_step
        k = 0
        while not self.closed:
            for i in range(n):
                if self.closed:
                    return
                frame = seq[i]
                if k:
                    frame = _shifted(frame, k * span, k * seq_span)
                pacer.wait(frame.stamp_ns)
                yield frame
            if not self.loop:
                return
            k += 1

    def info(self) -> dict:
        return {**super().info(), "path": str(self.sequence.path), "format": self.sequence.format,
                "frames_per_pass": len(self.sequence), "rate": self.rate, "loop": self.loop}


def _shifted(frame: DepthFrame, dt_ns: int, dseq: int) -> DepthFrame:
    from dataclasses import replace

    return replace(frame, stamp_ns=frame.stamp_ns + dt_ns, seq=frame.seq + dseq)
