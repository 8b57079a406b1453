"""Fuzzing depth PNG reading: valid 16-bit PNGs and images of other modes, their bytes truncated, bit-flipped or
spliced, chunks rewritten with valid CRCs (huge or zero sizes, other bit depths), random bytes.

Property: ``read_depth_png`` returns (H, W) float32 metres (NaN where there is no measurement, else finite and > 0)
or raises ``ValueError`` naming the file.
"""

from __future__ import annotations

import io
import struct
import tempfile
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from drivers.depth_png import read_depth_png
from test_fuzz_common import Target, fuzz_settings, outcome


def png_bytes(arr: np.ndarray, mode: str | None = None) -> bytes:
    buf = io.BytesIO()
    (Image.fromarray(arr, mode=mode) if mode else Image.fromarray(arr)).save(buf, format="PNG")
    return buf.getvalue()


def chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)


def raw_png(width: int, height: int, bit_depth: int, color_type: int, rows: bytes) -> bytes:
    """A PNG assembled by hand (valid CRCs), whatever its header claims."""
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, color_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")


@st.composite
def images(draw) -> bytes:
    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    kind = draw(st.integers(0, 7))
    if kind <= 1:
        values = draw(st.sampled_from([0, 1, 5000, 65535, None]))
        arr = (np.full((h, w), values, np.uint16) if values is not None
               else np.random.default_rng(draw(st.integers(0, 99))).integers(0, 65536, (h, w)).astype(np.uint16))
        data = png_bytes(arr)
    elif kind == 2:  # other modes
        mode = draw(st.sampled_from(["L", "RGB", "RGBA", "LA", "I", "F", "1", "P"]))
        base = np.random.default_rng(draw(st.integers(0, 99))).integers(0, 255, (h, w, 4)).astype(np.uint8)
        img = Image.fromarray(base, "RGBA").convert(mode)
        if mode == "I":
            img = Image.fromarray(np.random.default_rng(0).integers(-(2**31), 2**31 - 1, (h, w)).astype(np.int32))
        buf = io.BytesIO()
        img.save(buf, format="PNG" if mode not in ("F", "I") else "TIFF")
        data = buf.getvalue()
    elif kind == 3:  # a hand-made header: any size, bit depth and colour type, any rows
        width = draw(st.sampled_from([0, 1, 7, 2**16, 2**31 - 1, 2**32 - 1, 30_000]))
        height = draw(st.sampled_from([0, 1, 3, 2**16, 2**31 - 1, 30_000]))
        data = raw_png(width, height, draw(st.sampled_from([1, 2, 4, 8, 16, 3, 0, 255])),
                       draw(st.sampled_from([0, 2, 3, 4, 6, 1, 7])), draw(st.binary(max_size=64)))
    elif kind == 4:
        return draw(st.binary(max_size=300))
    else:
        data = png_bytes(np.random.default_rng(draw(st.integers(0, 99))).integers(0, 65536, (h, w)).astype(np.uint16))
    # Mutations of the bytes.
    b = bytearray(data)
    m = draw(st.integers(0, 4))
    if m == 1:
        b = b[: draw(st.integers(0, len(b) - 1))]
    elif m == 2:
        for _ in range(draw(st.integers(1, 6))):
            bit = draw(st.integers(0, len(b) * 8 - 1))
            b[bit // 8] ^= 1 << (bit % 8)
    elif m == 3:
        i = draw(st.integers(0, len(b)))
        b[i:i] = draw(st.binary(min_size=1, max_size=30))
    elif m == 4:
        i = draw(st.integers(8, max(8, len(b) - 1)))
        del b[i: i + draw(st.integers(1, 20))]
    return bytes(b)


def check_png(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzzed.png"
        path.write_bytes(data)
        depth = read_depth_png(path, 1000.0)
    assert depth.ndim == 2 and depth.dtype == np.float32 and depth.size > 0
    valid = ~np.isnan(depth)
    assert np.all(np.isfinite(depth[valid])) and np.all(depth[valid] > 0)


def run(data: bytes) -> str:
    return outcome(lambda: check_png(data), names="fuzzed.png")


TARGET = Target("png", "depth PNG", images(), run)


@fuzz_settings(150)
@given(images())
def test_fuzzed_pngs_read_or_raise_value_error(data):
    run(data)


def test_valid_png_reads_exactly():
    arr = np.array([[0, 1000], [65535, 2500]], np.uint16)
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "d.png"
        p.write_bytes(png_bytes(arr))
        depth = read_depth_png(p, 1000.0)
    np.testing.assert_array_equal(depth, np.array([[np.nan, 1.0], [65.535, 2.5]], np.float32))


def test_an_8_bit_png_is_refused_as_a_depth_image(tmp_path):
    """Eight bits cannot hold depth at any scale a camera uses: read as raw units, 200 at 5000 per metre was 4 cm
    everywhere, silently. Refused, naming the mode."""
    p = tmp_path / "grey8.png"
    Image.fromarray(np.full((4, 4), 200, np.uint8), "L").save(p)
    with pytest.raises(ValueError, match=r"grey8.png: expected a 16-bit greyscale depth PNG, got mode L"):
        read_depth_png(p, 5000.0)


# Regressions found by the fuzzer (each escaped before its fix).


def test_header_claiming_billions_of_pixels_is_refused_before_decoding(tmp_path):
    p = tmp_path / "bomb.png"
    p.write_bytes(raw_png(2**31 - 1, 1, 16, 0, b""))  # PIL's DecompressionBombError escaped before
    assert outcome(lambda: read_depth_png(p, 1000.0), names="bomb.png") == "error"
    p.write_bytes(raw_png(12_000, 12_000, 16, 0, b""))  # below PIL's bomb limit: a 288 MB decode before
    assert outcome(lambda: read_depth_png(p, 1000.0), names="bomb.png", timeout_s=5) == "error"


def test_huge_header_is_refused_without_pillows_bomb_warning(tmp_path):
    # 12,000 x 12,000 is above Pillow's warning limit (89 M pixels): the header check comes first, so no warning
    # reaches a live loop's log, only the error naming the file and the size.
    p = tmp_path / "bomb.png"
    p.write_bytes(raw_png(12_000, 12_000, 16, 0, b""))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"bomb\.png: image is 12000x12000"):
            read_depth_png(p, 1000.0)


def test_codec_value_errors_name_the_file(tmp_path):
    p = tmp_path / "short.png"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 5) + b"IHDR\x00\x00\x00\x01\x00" + b"\x00" * 4)
    assert outcome(lambda: read_depth_png(p, 1000.0), names="short.png") == "error"  # "Truncated IHDR chunk"
