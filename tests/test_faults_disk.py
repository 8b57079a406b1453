"""The disk filling up while a map or a recording is written: the previous file stays intact and readable, no
temporary file is left behind, and the error says what failed.

The full disk is simulated inside reloc.atomic (every important file goes through it): files opened there get a
number of bytes or files in total, then ENOSPC, as a real full file system gives (checked by hand on a 64 KiB tmpfs:
see docs/RELIABILITY.md). ``fsync`` and ``rename`` failing are simulated too (delayed allocation reports ENOSPC at
fsync; a vanished directory at rename).
"""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
from helpers import write_office_sequence

import reloc.atomic
from drivers.readers import open_sequence
from drivers.recorder import record
from drivers.sim_source import SimSource
from reloc.cli import main
from reloc.live.factory import load_plane_map
from reloc.mapping import load_map, save_map
from reloc.mapping.plane_map import PlaneMap


class _LimitedFile:
    def __init__(self, fh, disk):
        self._fh, self._disk = fh, disk

    def write(self, data):
        n = len(data.encode("utf-8") if isinstance(data, str) else data)
        if n > self._disk.free_bytes:
            part = self._disk.free_bytes
            self._disk.free_bytes = 0
            if part:
                self._fh.write(data[:part])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._disk.free_bytes -= n
        return self._fh.write(data)

    def __getattr__(self, name):
        return getattr(self._fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()


class FullDisk:
    """Stands in for ``os`` inside reloc.atomic: ``free_bytes`` bytes, or ``free_files`` files, then ENOSPC; or
    ``fail`` = "fsync" / "replace" failing every time."""

    def __init__(self, free_bytes: int = 1 << 40, free_files: int = 1 << 30, fail: str | None = None):
        self.free_bytes, self.free_files, self.fail = free_bytes, free_files, fail

    def __getattr__(self, name):
        return getattr(os, name)

    def fdopen(self, fd, mode, **kw):
        fh = os.fdopen(fd, mode, **kw)
        self.free_files -= 1
        if self.free_files < 0:
            self.free_bytes = 0
        return _LimitedFile(fh, self)

    def fsync(self, fd):
        if self.fail == "fsync":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return os.fsync(fd)

    def replace(self, src, dst):
        if self.fail == "replace":
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        return os.replace(src, dst)


def _leftovers(folder):
    return sorted(p.name for p in folder.rglob("*") if p.name.endswith(".tmp"))


@pytest.fixture(scope="module")
def maps():
    planes, _ = load_plane_map("sim:living_room")
    old = PlaneMap(planes.subset(np.arange(len(planes) // 2)), np.full(len(planes) // 2, 3))
    new = PlaneMap(planes, np.full(len(planes), 5))
    return old, new


@pytest.mark.parametrize("disk", [FullDisk(free_bytes=2000), FullDisk(fail="fsync"), FullDisk(fail="replace")],
                         ids=["write", "fsync", "replace"])
def test_saving_a_map_on_a_full_disk_keeps_the_previous_map(tmp_path, maps, monkeypatch, disk):
    old, new = maps
    path = tmp_path / "map.npz"
    save_map(path, old)
    before = path.read_bytes()
    monkeypatch.setattr(reloc.atomic, "os", disk)
    with pytest.raises(OSError) as err:
        save_map(path, new)
    monkeypatch.undo()
    # The error names the file and says it was not replaced.
    msg = str(err.value)
    assert err.value.errno in (errno.ENOSPC, errno.EIO) and str(path) in msg and "as it was" in msg
    assert path.read_bytes() == before and _leftovers(tmp_path) == []
    back = load_map(path)
    assert len(back) == len(old) and np.array_equal(back.observations, old.observations)


def test_a_recording_on_a_full_disk_stops_with_a_clear_error_and_what_was_flushed_replays(tmp_path, monkeypatch):
    out = tmp_path / "rec"
    src = SimSource("living_room", n_frames=90, camera="oak-d", width=160, height=100, rate="fast")
    # Files per frame: a depth and a label PNG; every 30 frames depth.txt, groundtruth.txt, gravity.txt and
    # recording.json; camera.yaml once. Room for 1 + 2 * 45 + 4 files: the disk fills at frame 46.
    monkeypatch.setattr(reloc.atomic, "os", FullDisk(free_files=1 + 2 * 45 + 4))
    with pytest.raises(OSError) as err:
        record(src, out, n_frames=90)
    monkeypatch.undo()
    src.close()
    assert err.value.errno == errno.ENOSPC and f"{out / 'depth'}/" in str(err.value)  # the frame that did not fit
    assert _leftovers(out) == []
    # The sequence on disk is the one flushed before the disk filled: 30 frames, every one readable, poses and all.
    seq = open_sequence(out)
    assert len(seq) == 30
    for i in (0, 29):
        f = seq[i]
        assert f.depth_m.shape == (100, 160) and np.isfinite(f.depth_m).any() and f.T_world_cam is not None


@pytest.fixture(scope="module")
def small_sequence(tmp_path_factory):
    return write_office_sequence(tmp_path_factory.mktemp("seq") / "office", 60)


def test_reloc_map_build_on_a_full_disk_is_one_line_and_keeps_the_previous_map(small_sequence, tmp_path, capsys,
                                                                                monkeypatch):
    out = tmp_path / "map.npz"
    assert main(["map", "build", str(small_sequence), "-o", str(out), "--source", "oracle", "--quiet"]) == 0
    before = out.read_bytes()
    capsys.readouterr()
    monkeypatch.setattr(reloc.atomic, "os", FullDisk(free_bytes=1000))
    assert main(["map", "build", str(small_sequence), "-o", str(out), "--source", "oracle", "--quiet"]) == 1
    monkeypatch.undo()
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: [Errno {errno.ENOSPC}] {os.strerror(errno.ENOSPC)}: writing {out} failed; the file is "
                   "as it was before"]
    assert out.read_bytes() == before and _leftovers(tmp_path) == [] and len(load_map(out)) > 0
