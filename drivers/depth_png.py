"""16-bit depth PNG files (TUM RGB-D, ICL-NUIM, 7-Scenes): read to metres, write from metres.

Stored value = round(depth_m * depth_scale) as uint16; 0 means no measurement. Pillow does the PNG codec.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from reloc.atomic import atomic_write

__all__ = ["read_depth_png_raw", "read_depth_png", "write_depth_png", "write_label_png", "read_label_png"]

# Larger images are refused before decoding (a corrupted or hostile header can claim billions of pixels).
MAX_PIXELS = 4096 * 4096


def _png_header_size(path) -> tuple[int, int] | None:
    """``(width, height)`` from a PNG's IHDR chunk, or None when the file does not start like a PNG."""
    with open(path, "rb") as f:
        head = f.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", head[16:24])


def read_depth_png_raw(path: str | os.PathLike) -> np.ndarray:
    """The raw (H, W) uint16 values of a 16-bit single-channel PNG. Raises ValueError naming the file."""
    from PIL import Image, UnidentifiedImageError

    try:
        # The size in the header is checked before Pillow opens the file: Pillow warns (DecompressionBombWarning)
        # from 89 M pixels on, a warning per bad file in a live loop's log, where this limit is far lower anyway.
        size = _png_header_size(path)
        if size is not None and size[0] * size[1] > MAX_PIXELS:
            raise ValueError(f"{path}: image is {size[0]}x{size[1]}, larger than any depth camera's "
                             f"({MAX_PIXELS} pixels at most)")
        with Image.open(path) as img:
            if img.width * img.height > MAX_PIXELS:  # checked before decoding anything
                raise ValueError(f"{path}: image is {img.width}x{img.height}, larger than any depth camera's "
                                 f"({MAX_PIXELS} pixels at most)")
            img.load()
            mode = img.mode
            arr = np.array(img)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: depth image not found") from None
    except (UnidentifiedImageError, Image.DecompressionBombError, OSError, SyntaxError, EOFError, struct.error,
            zlib.error) as exc:
        raise ValueError(f"{path}: not a readable PNG image ({exc})") from None
    except ValueError as exc:  # the codec's own complaints ("Truncated IHDR chunk"), named with the file
        if str(path) in str(exc):
            raise
        raise ValueError(f"{path}: not a readable PNG image ({exc})") from None
    if arr.ndim != 2:
        raise ValueError(f"{path}: expected a single-channel 16-bit depth image, got mode {mode} with shape {arr.shape}")
    if mode not in ("I;16", "I;16B", "I", "I;16L"):  # not "L": 8 bits would read as 0-255 raw units
        raise ValueError(f"{path}: expected a 16-bit greyscale depth PNG, got mode {mode}")
    if arr.dtype != np.uint16:
        if arr.min(initial=0) < 0 or arr.max(initial=0) > 65535:
            raise ValueError(f"{path}: depth values outside 0..65535")
        arr = arr.astype(np.uint16)
    return arr


def read_depth_png(path: str | os.PathLike, depth_scale: float, invalid_raw: tuple[int, ...] = (0,)) -> np.ndarray:
    """Depth in metres (H, W) float32; raw values in ``invalid_raw`` (0 by default) become NaN."""
    raw = read_depth_png_raw(path)
    depth = raw.astype(np.float32) / np.float32(depth_scale)
    for bad in invalid_raw:
        depth[raw == bad] = np.nan
    return depth


def write_depth_png(path: str | os.PathLike, depth_m: np.ndarray, depth_scale: float) -> None:
    """Write metres as uint16 ``round(depth_m * depth_scale)``; NaN, inf, <= 0 and out-of-range become 0. Atomic."""
    d = np.asarray(depth_m, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth_m: expected a 2-D array, got shape {d.shape}")
    raw = np.rint(np.where(np.isfinite(d) & (d > 0), d, 0.0) * depth_scale)
    raw[(raw < 0) | (raw > 65535)] = 0
    _write_u16(path, raw.astype(np.uint16))


def write_label_png(path: str | os.PathLike, labels: np.ndarray) -> None:
    """Write a (H, W) label image (plane ids 0..65535, 0 = none) as a 16-bit PNG. Atomic."""
    lab = np.asarray(labels)
    if lab.ndim != 2 or lab.min(initial=0) < 0 or lab.max(initial=0) > 65535:
        raise ValueError(f"labels: expected a 2-D array of ids in 0..65535, got shape {lab.shape}")
    _write_u16(path, lab.astype(np.uint16))


def read_label_png(path: str | os.PathLike) -> np.ndarray:
    """(H, W) int32 plane ids from a 16-bit label PNG."""
    return read_depth_png_raw(path).astype(np.int32)


def _write_u16(path: str | os.PathLike, raw: np.ndarray) -> None:
    from PIL import Image

    img = Image.fromarray(np.ascontiguousarray(raw, dtype=np.uint16))
    with atomic_write(Path(path), "wb") as fh:
        img.save(fh, format="PNG", compress_level=1)
