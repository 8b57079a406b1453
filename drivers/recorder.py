"""Recording frames from any source into the TUM RGB-D layout, so recordings replay, map and evaluate like datasets.

Layout of the output folder (read back by :func:`drivers.readers.open_sequence`):

- ``depth/<t>.png``: uint16, ``raw = round(depth_m * depth_scale)``, 0 = no measurement; ``<t>`` is the stamp in
  seconds with 9 decimals, so ``stamp_ns`` survives the round trip exactly.
- ``depth.txt`` (``timestamp filename``) and ``camera.yaml`` (fx, fy, cx, cy, width, height, depth_scale).
- ``groundtruth.txt`` / ``odometry.txt`` (``timestamp tx ty tz qx qy qz qw``, camera to world / odometry frame)
  for frames whose pose is ground truth / odometry.
- ``gravity.txt`` (``timestamp gx gy gz``: unit, pointing down, camera frame) for frames with gravity.
- ``labels/<t>.png`` when frames carry plane labels (the simulator).
- ``recording.json``: the source's description, frame counts and what was skipped.

Every file is written atomically (a temporary file renamed over the target). The text files are rewritten every
``flush_every`` frames and at close, so an interrupted recording is a valid, shorter sequence.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from reloc.atomic import atomic_write_text
from reloc.camera import DepthFrame, Intrinsics
from reloc.transforms import tum_from_transform

from drivers.depth_png import write_depth_png, write_label_png
from drivers.readers import noise_law_entry

__all__ = ["MIN_DEPTH_SCALE", "Recorder", "RecordSummary", "SEQUENCE_FILES", "clear_sequence", "record", "stamp_text"]

_POSE_FILES = {"groundtruth": "groundtruth.txt", "odometry": "odometry.txt"}
MIN_DEPTH_SCALE = 1000.0  # integers per metre written at least: millimetres (a uint16 image then holds 65.5 m)


#: Every file of a sequence folder that a reader may take (drivers.readers) and a writer may leave: what
#: :func:`clear_sequence` removes before another sequence is written over it.
SEQUENCE_FILES = ("depth.txt", "labels.txt", "groundtruth.txt", "odometry.txt", "gravity.txt", "accelerometer.txt",
                  "camera.yaml", "recording.json", "sim.json", "planes.json")


def clear_sequence(out: Path) -> None:
    """Remove the sequence in folder ``out`` (its depth and label images, :data:`SEQUENCE_FILES` and an emptied
    ``labels/``) so that a sequence written over it keeps nothing of it: a leftover ``labels/`` would make the reader
    ask a label image of every new frame, a leftover ``sim.json`` give it the simulator's noise law."""
    for sub in ("depth", "labels"):
        for p in (out / sub).glob("*.png"):
            p.unlink()
    for name in SEQUENCE_FILES:
        (out / name).unlink(missing_ok=True)
    if (out / "labels").is_dir() and not any((out / "labels").iterdir()):
        (out / "labels").rmdir()


def stamp_text(stamp_ns: int) -> str:
    """Seconds with 9 decimals, exactly (``1305031102160407000`` -> ``"1305031102.160407000"``)."""
    s = int(stamp_ns)
    if s < 0:
        raise ValueError(f"stamp_ns: expected a non-negative timestamp, got {s}")
    return f"{s // 1_000_000_000}.{s % 1_000_000_000:09d}"


@dataclass
class RecordSummary:
    out_dir: str
    frames_written: int = 0
    frames_skipped: int = 0
    skip_reasons: list[str] = field(default_factory=list)
    with_pose: dict[str, int] = field(default_factory=dict)
    with_gravity: int = 0
    unrepresentable_pixels: int = 0
    seconds: float = 0.0
    noise_law: tuple[str, float] | None = None  # the camera's depth noise law, stored in recording.json

    def text(self) -> str:
        poses = ", ".join(f"{n} {k}" for k, n in self.with_pose.items()) or "none"
        lines = [f"wrote {self.frames_written} frames to {self.out_dir} in {self.seconds:.1f} s "
                 f"(poses: {poses}; gravity: {self.with_gravity})"]
        if self.unrepresentable_pixels:
            lines.append(f"  {self.unrepresentable_pixels} pixels beyond the uint16 range were written as 0")
        if self.frames_skipped:
            lines.append(f"  skipped {self.frames_skipped} frames; first reason: {self.skip_reasons[0]}")
        if self.noise_law is not None:
            lines.append(f"  the camera's depth noise ({self.noise_law[0]}, {self.noise_law[1]:.3g}) goes with it")
        return "\n".join(lines)


class Recorder:
    """Writes frames one by one (``write``) into ``out_dir``; ``close()`` (or leaving ``with``) finishes the files.

    ``depth_scale``: stored integers per metre (default: the frames' intrinsics', at least
    :data:`MIN_DEPTH_SCALE`). Raises ValueError when
    ``out_dir`` already holds a sequence (unless ``overwrite``), and from ``write`` for a frame whose stamp does
    not increase or whose intrinsics differ from the first frame's (nothing of that frame is written).
    """

    def __init__(self, out_dir: str | os.PathLike, *, overwrite: bool = False, depth_scale: float | None = None,
                 flush_every: int = 30, metadata: dict | None = None) -> None:
        self.out = Path(out_dir)
        if self.out.exists() and not self.out.is_dir():
            raise ValueError(f"out_dir: {self.out} exists and is not a directory")
        if (self.out / "depth.txt").exists():
            if not overwrite:
                raise ValueError(f"out_dir: {self.out} already holds a sequence (depth.txt); use overwrite to replace it")
            clear_sequence(self.out)
        if depth_scale is not None and not depth_scale > 0:
            raise ValueError(f"depth_scale: expected > 0, got {depth_scale}")
        if not isinstance(flush_every, int) or flush_every < 1:
            raise ValueError(f"flush_every: expected a positive integer, got {flush_every!r}")
        (self.out / "depth").mkdir(parents=True, exist_ok=True)
        self.depth_scale = depth_scale
        self.flush_every = flush_every
        self.metadata = dict(metadata or {})
        self.summary = RecordSummary(out_dir=str(self.out))
        self._intrinsics: Intrinsics | None = None
        self._last_stamp: int | None = None
        # One entry per written frame: (depth line, pose file or None, pose line, gravity line or None). A frame is
        # added by one append, so an interrupt (Ctrl-C, SIGTERM) never leaves it in one index and not in another.
        self._frames: list[tuple[str, str | None, str, str | None]] = []
        self._t0 = time.monotonic()
        self._closed = False

    def write(self, frame: DepthFrame) -> None:
        if self._closed:
            raise RuntimeError(f"{self.out}: the recorder is closed")
        if self._last_stamp is not None and frame.stamp_ns <= self._last_stamp:
            raise ValueError(f"frame {frame.seq}: stamp_ns {frame.stamp_ns} does not increase (last {self._last_stamp})")
        if self._intrinsics is None:
            self._intrinsics = frame.intrinsics
            if self.depth_scale is None:
                # The source's own units, unless coarser than a millimetre: a float depth source (a 32FC1 bag,
                # scale 1 per metre) would be rounded to whole metres in the uint16 images.
                self.depth_scale = max(float(frame.intrinsics.depth_scale), MIN_DEPTH_SCALE)
            self._write_camera_yaml()
        elif frame.intrinsics != self._intrinsics:
            raise ValueError(f"frame {frame.seq}: intrinsics {frame.intrinsics} differ from the first frame's "
                             f"{self._intrinsics}; a sequence has one camera")
        name = stamp_text(frame.stamp_ns)
        d = frame.depth_m
        self.summary.unrepresentable_pixels += int(np.count_nonzero(np.isfinite(d) & (d * self.depth_scale > 65535.5)))
        write_depth_png(self.out / "depth" / f"{name}.png", d, self.depth_scale)
        if frame.labels is not None:
            write_label_png(self.out / "labels" / f"{name}.png", frame.labels)
        pose_file = pose_line = gravity_line = None
        if frame.T_world_cam is not None and frame.pose_source in _POSE_FILES:
            pose_file = _POSE_FILES[frame.pose_source]
            pose_line = f"{name} " + " ".join(f"{v:.9f}" for v in tum_from_transform(frame.T_world_cam))
        if frame.gravity_cam is not None:
            gravity_line = f"{name} " + " ".join(f"{v:.9f}" for v in frame.gravity_cam)
        self._frames.append((f"{name} depth/{name}.png", pose_file, pose_line, gravity_line))
        self._last_stamp = frame.stamp_ns
        # Counted as we go (flush() recounts from the frames, in case an interrupt fell in between).
        self.summary.frames_written = len(self._frames)
        if pose_file is not None:
            self.summary.with_pose[pose_file[:-4]] = self.summary.with_pose.get(pose_file[:-4], 0) + 1
        self.summary.with_gravity += gravity_line is not None
        if self.summary.frames_written % self.flush_every == 0:
            self.flush()

    def skip(self, reason: str) -> None:
        """Count a frame that could not be written (kept in the summary and recording.json)."""
        self.summary.frames_skipped += 1
        if len(self.summary.skip_reasons) < 20:
            self.summary.skip_reasons.append(reason)

    def flush(self) -> None:
        """Rewrite the text files (atomically) with every frame written so far."""
        headers = {
            "depth.txt": "# depth maps\n# timestamp filename\n",
            "groundtruth.txt": "# ground truth trajectory (camera to world)\n# timestamp tx ty tz qx qy qz qw\n",
            "odometry.txt": "# odometry (camera to odometry frame)\n# timestamp tx ty tz qx qy qz qw\n",
            "gravity.txt": "# gravity direction (unit, pointing down, camera frame)\n# timestamp gx gy gz\n",
        }
        self._count()
        lines_of: dict[str, list[str]] = {"depth.txt": [], "groundtruth.txt": [], "odometry.txt": [], "gravity.txt": []}
        for depth_line, pose_file, pose_line, gravity_line in self._frames:
            lines_of["depth.txt"].append(depth_line)
            if pose_file is not None:
                lines_of[pose_file].append(pose_line)
            if gravity_line is not None:
                lines_of["gravity.txt"].append(gravity_line)
        for fname, lines in lines_of.items():
            if lines:
                atomic_write_text(self.out / fname, headers[fname] + "\n".join(lines) + "\n")
        self.summary.seconds = time.monotonic() - self._t0
        info = {"summary": self.summary.__dict__, **self.metadata}
        atomic_write_text(self.out / "recording.json", json.dumps(info, indent=2, default=str) + "\n")

    def _count(self) -> None:
        """The summary's frame, pose and gravity counts, from the frames written."""
        self.summary.frames_written = len(self._frames)
        with_pose: dict[str, int] = {}
        for _, pose_file, _, _ in self._frames:
            if pose_file is not None:
                key = pose_file[:-4]
                with_pose[key] = with_pose.get(key, 0) + 1
        self.summary.with_pose = with_pose
        self.summary.with_gravity = sum(g is not None for *_, g in self._frames)

    def close(self) -> RecordSummary:
        if not self._closed:
            self.flush()
            self._closed = True
        return self.summary

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None or not issubclass(exc_type, OSError):
            self.close()
            return
        # Leaving on a system error (a full disk): keep what can still be kept, but report the error that stopped
        # the recording, not a later one from the same cause.
        try:
            self.close()
        except OSError:
            pass

    def _write_camera_yaml(self) -> None:
        k = {**self._intrinsics.as_dict(), "depth_scale": float(self.depth_scale)}
        atomic_write_text(self.out / "camera.yaml", "# depth camera intrinsics (recorded)\n" + yaml.safe_dump(k, sort_keys=False))


def record(source, out_dir: str | os.PathLike, *, n_frames: int | None = None, duration_s: float | None = None,
           overwrite: bool = False, depth_scale: float | None = None, extra_files: dict[str, str] | None = None,
           progress: bool = False) -> RecordSummary:
    """Record frames of an open ``source`` (a :class:`drivers.source.FrameSource`) until it ends, ``n_frames``
    were written or ``duration_s`` passed. A frame that cannot be written is counted and skipped, not fatal.
    ``extra_files`` (name -> text) are written beside the sequence (``planes.json`` of a simulated scene)."""
    if n_frames is not None and (not isinstance(n_frames, int) or n_frames < 1):
        raise ValueError(f"n_frames: expected a positive integer, got {n_frames!r}")
    if duration_s is not None and not duration_s > 0:
        raise ValueError(f"duration_s: expected a positive number of seconds, got {duration_s!r}")
    bar = None
    if progress:
        from reloc.progress import progress_bar

        bar = progress_bar(total=n_frames, unit="frame", desc="record", leave=False)
    t0 = time.monotonic()
    # The camera's noise law goes with the recording, so that maps and queries built from it are extracted with it.
    law = source.noise_law()
    meta = {"source": source.info(), "noise_law": noise_law_entry(law)}
    with Recorder(out_dir, overwrite=overwrite, depth_scale=depth_scale, metadata=meta) as rec:
        rec.summary.noise_law = law
        for name, text in (extra_files or {}).items():
            atomic_write_text(rec.out / name, text)
        try:
            for frame in source:
                try:
                    rec.write(frame)
                except ValueError as exc:
                    rec.skip(str(exc))
                if bar is not None:
                    bar.update(1)
                if n_frames is not None and rec.summary.frames_written >= n_frames:
                    break
                if duration_s is not None and time.monotonic() - t0 >= duration_s:
                    break
        finally:
            if bar is not None:
                bar.close()
    return rec.summary
