"""Atomic file writes: a temporary file in the same directory, flushed and fsynced, then renamed over the target.

A crash or a full disk never leaves a half-written file under the final name: readers see the old file or the new
one, nothing in between. The file gets the permissions an ordinary ``open`` would give it (``0o666`` less the umask),
or keeps those of the file it replaces, not the private ``0o600`` of a temporary file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from pathlib import Path
from typing import IO, Iterator

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "make_parent"]

_CREATE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)


def make_parent(target: Path) -> None:
    """Create the folders ``target`` goes in; ``NotADirectoryError`` naming the file in the way when one of them is
    a file (``mkdir`` says only "File exists: 'out'")."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocking = next((p for p in (target.parent, *target.parent.parents) if p.exists() and not p.is_dir()), None)
        raise NotADirectoryError(errno.ENOTDIR, f"cannot make the folder of {target}: {blocking or target.parent} "
                                                "is a file, not a folder") from None


def _umask() -> int:
    """The process umask, read without changing it where the platform allows (os.umask is process-wide)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _final_mode(target: Path) -> int:
    """Mode bits for ``target``: those of the file being replaced, else 0o666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        return 0o666 & ~_umask()


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """Context manager yielding a file object; on success the file replaces ``path`` atomically.

    On any exception the temporary file is removed and ``path`` is left as it was.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode: expected 'w' or 'wb', got {mode!r}")
    target = Path(path)
    make_parent(target)
    mode_bits = _final_mode(target)
    # The temporary file's name is known before it exists, so that an interrupt (Ctrl-C, SIGTERM turned into an
    # exception) arriving right after it is created still finds it to remove: with tempfile.mkstemp the name only
    # comes back once the file exists, and a SIGINT in between left it behind (seen in CI).
    tmp = fd = None
    try:
        for _ in range(100):
            tmp = target.parent / f".{target.name}.{secrets.token_hex(6)}.tmp"
            try:
                fd = os.open(tmp, _CREATE_FLAGS, 0o600)
                break
            except FileExistsError:
                tmp = None
        else:
            raise FileExistsError(errno.EEXIST, f"no free temporary file name beside {target}")
        with contextlib.suppress(OSError):  # created 0o600; a file system without modes keeps its own
            os.chmod(tmp, mode_bits)
        fh = os.fdopen(fd, mode, **({"encoding": "utf-8"} if mode == "w" else {}))
        fd = None  # the file object owns it now
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException as exc:
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if isinstance(exc, OSError) and exc.errno is not None and exc.filename is None:
            # "No space left on device" alone does not say which file; name it, and that it was not replaced.
            raise OSError(exc.errno, f"{exc.strerror or exc}: writing {target} failed; the file is as it was "
                                     "before") from exc
        raise
    # Make the rename itself durable where the platform allows it.
    with contextlib.suppress(OSError):
        dir_fd = os.open(target.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_write(path, "wb") as fh:
        fh.write(data)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_write(path, "w") as fh:
        fh.write(text)
