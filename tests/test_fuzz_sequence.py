"""Fuzzing sequence folders: valid tiny sequences of each layout (TUM RGB-D with poses, gravity or accelerometer and
labels; 7-Scenes; a pose folder; a single PNG with an OpenCV XML calibration), then files deleted or added, PNGs
corrupted or of the wrong size, text lines (depth lists, poses, timestamps, IMU rows, intrinsics) with tokens
replaced, columns dropped or added, lines repeated or swapped, non-UTF-8 bytes and camera.yaml of any content.

Property: ``open_sequence`` and reading every frame give frames of the intrinsics' size with finite rigid poses and
unit gravity (or none), and intrinsics exactly as the file states them; or raise ``ValueError`` /
``FileNotFoundError`` naming a file of the folder.
"""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np
import yaml
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from drivers.readers import open_sequence
from test_fuzz_common import Target, fuzz_settings, outcome

W, H = 8, 6
CAMERA = {"fx": 10.0, "fy": 10.0, "cx": 3.5, "cy": 2.5, "width": W, "height": H, "depth_scale": 1000.0}
XML = """<?xml version="1.0"?>
<opencv_storage><IR_intrinsic_params type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>
<data>10. 0. 3.5 0. 10. 2.5 0. 0. 1.</data></IR_intrinsic_params></opencv_storage>
"""


def png(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG")
    return buf.getvalue()


def depth_png(seed: int, w: int = W, h: int = H) -> bytes:
    return png(np.random.default_rng(seed).integers(0, 4000, (h, w)).astype(np.uint16))


def layout(kind: str, n: int) -> dict[str, bytes]:
    """A valid sequence folder of ``n`` frames as {relative path: bytes}."""
    files: dict[str, bytes] = {}
    cam = yaml.safe_dump(CAMERA).encode()
    if kind == "tum":
        files["camera.yaml"] = cam
        files["depth.txt"] = "".join(f"{1.0 + i / 30:.6f} depth/{i}.png\n" for i in range(n)).encode()
        files["groundtruth.txt"] = "# t tx ty tz qx qy qz qw\n".encode() + "".join(
            f"{1.0 + i / 30:.6f} {i * 0.1} 0 1.5 0 0 0 1\n" for i in range(n)).encode()
        files["gravity.txt"] = "".join(f"{1.0 + i / 30:.6f} 0 1 0\n" for i in range(n)).encode()
        files["accelerometer.txt"] = "".join(f"{1.0 + i / 30:.6f} 0 9.8 0.1\n" for i in range(n)).encode()
        for i in range(n):
            files[f"depth/{i}.png"] = depth_png(i)
            files[f"labels/{i}.png"] = png(np.zeros((H, W), np.uint16))
        files["planes.json"] = b'{"planes": []}'
    elif kind == "7scenes":
        files["camera-intrinsics.txt"] = b"10 0 3.5\n0 10 2.5\n0 0 1\n"
        for i in range(n):
            files[f"frame-{i:06d}.depth.png"] = depth_png(i)
            files[f"frame-{i:06d}.pose.txt"] = f"1 0 0 {i * 0.1}\n0 1 0 0\n0 0 1 1.5\n0 0 0 1\n".encode()
    elif kind == "pose_folder":
        files["camera.yaml"] = cam
        files["pose.txt"] = "".join(f"{i * 0.1} 0 1.5 0 0 0 1\n" for i in range(n)).encode()
        for i in range(n):
            files[f"depth/{i + 1}.png"] = depth_png(i)
    else:
        files["frame.png"] = depth_png(0)
        files["calib.xml"] = XML.encode()
    return files


TOKENS = ["nan", "inf", "-inf", "1e400", "1e30", "-1e30", "", "abc", "0", "-1", "0x10", "1_0", "１", "9" * 40,
          "1e-400", "2.5", "-0", "depth/0.png", "../x.png", "/etc/passwd", "depth", "\x00"]


def _mutate_text(data: bytes, draw) -> bytes:
    lines = data.decode("utf-8", errors="replace").splitlines() or [""]
    i = draw(st.integers(0, len(lines) - 1))
    tok = lines[i].split()
    kind = draw(st.integers(0, 6))
    if kind == 0 and tok:  # a token replaced
        tok[draw(st.integers(0, len(tok) - 1))] = draw(st.one_of(st.sampled_from(TOKENS), st.text(max_size=4)))
        lines[i] = " ".join(tok)
    elif kind == 1 and tok:  # a column dropped
        del tok[draw(st.integers(0, len(tok) - 1))]
        lines[i] = " ".join(tok)
    elif kind == 2:  # a column added
        lines[i] = lines[i] + " " + draw(st.sampled_from(TOKENS))
    elif kind == 3:  # a line repeated
        lines.insert(i, lines[i])
    elif kind == 4:  # lines swapped
        j = draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == 5:  # a line deleted
        del lines[i]
    else:  # a raw byte inserted (non-UTF-8 included)
        out = bytearray("\n".join(lines).encode())
        out.insert(draw(st.integers(0, len(out))), draw(st.integers(0, 255)))
        return bytes(out)
    return ("\n".join(lines) + "\n").encode()


camera_values = st.one_of(st.integers(-5, 20), st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
                          st.none(), st.text(max_size=4), st.just(2**40), st.just(8.5), st.lists(st.integers(), max_size=2))


@st.composite
def sequence_folders(draw) -> dict[str, bytes]:
    kind = draw(st.sampled_from(["tum", "tum", "7scenes", "pose_folder", "single_png"]))
    files = layout(kind, draw(st.integers(1, 3)))
    for _ in range(draw(st.integers(0, 3))):
        names = sorted(files)
        if not names:
            break
        name = draw(st.sampled_from(names))
        op = draw(st.integers(0, 7))
        if op == 0:
            del files[name]
        elif op == 1:  # an extra file
            extra = draw(st.sampled_from(["extra.png", "frame-000099.depth.png", "pose.txt", "depth.txt", "b.xml",
                                          "camera.yaml", "labels/9.png", "depth/99.png", "gravity.txt",
                                          "odometry.txt"]))
            files[extra] = draw(st.sampled_from([depth_png(7), depth_png(7, 5, 4), b"", b"0 0 0 0 0 0 0 1\n",
                                                 XML.encode()]))
        elif name.endswith(".png"):
            if op == 2:  # another size
                w, h = draw(st.sampled_from([(W + 1, H), (W, H - 1), (1, 1), (H, W)]))
                files[name] = depth_png(3, w, h)
            elif op == 3:  # another mode
                files[name] = png(np.zeros((H, W, 3), np.uint8))
            else:  # corrupted
                b = bytearray(files[name]) or bytearray(b"\x00")
                if draw(st.booleans()):
                    b = b[: draw(st.integers(0, len(b) - 1))]
                else:
                    b[draw(st.integers(0, len(b) - 1))] ^= 1 << draw(st.integers(0, 7))
                files[name] = bytes(b)
        elif name == "camera.yaml" and op <= 4:
            cam = dict(CAMERA)
            key = draw(st.sampled_from(sorted(cam)))
            if draw(st.booleans()):
                del cam[key]
            else:
                cam[key] = draw(camera_values)
            files[name] = yaml.safe_dump(cam).encode() if op < 4 else draw(st.sampled_from(
                [b"", b"[1, 2]", b"fx: [", b"- a", b"\xff\xfe", b"[" * 3000]))
        else:
            files[name] = _mutate_text(files[name], draw)
    return files


def check_sequence(files: dict[str, bytes]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "fuzzseq"
        for rel, data in files.items():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_bytes(data)
        seq = open_sequence(root)
        k = seq.intrinsics
        if "camera.yaml" in files and seq.format in ("tum", "pose_folder"):
            stated = yaml.safe_load(files["camera.yaml"].decode())
            for key in ("width", "height"):  # no silent rounding of an image size
                assert type(stated[key]) is int and stated[key] == getattr(k, key), (key, stated[key])
            for key in ("fx", "fy", "cx", "cy"):
                assert float(stated[key]) == getattr(k, key)
        assert len(seq) >= 1 and np.all(np.diff(seq.stamps_ns) > 0)
        for frame in seq:
            assert frame.depth_m.shape == k.shape
            d = frame.depth_m[~np.isnan(frame.depth_m)]
            assert np.all(np.isfinite(d)) and np.all(d > 0)
            if frame.T_world_cam is not None:
                assert np.isfinite(frame.T_world_cam).all()
            if frame.gravity_cam is not None:
                assert abs(np.linalg.norm(frame.gravity_cam) - 1) < 1e-9
            if frame.labels is not None:
                assert frame.labels.shape == k.shape


def run(files: dict[str, bytes]) -> str:
    return outcome(lambda: check_sequence(files), names="fuzzseq", clear=(ValueError, FileNotFoundError))


TARGET = Target("sequence", "sequence folder", sequence_folders(), run)


def test_every_valid_layout_opens():
    for kind in ("tum", "7scenes", "pose_folder", "single_png"):
        assert run(layout(kind, 2)) == "ok", kind


@fuzz_settings(120)
@given(sequence_folders())
def test_fuzzed_sequence_folders_open_or_raise_naming_a_file(files):
    run(files)


# Regressions found by the fuzzer (each escaped before its fix).


def test_timestamps_beyond_int64_nanoseconds_are_value_errors():
    for name in ("depth.txt", "groundtruth.txt", "accelerometer.txt"):
        for stamp in ("1e30", "-1e30", "1e999999999"):  # OverflowError (or a billion-digit int) before
            files = layout("tum", 1)
            del files["gravity.txt"]
            text = files[name].decode()
            files[name] = text.replace("1.000000", stamp, 1).encode()
            assert run(files) == "error", (name, stamp)


def test_intrinsics_errors_name_their_file():
    files = layout("7scenes", 1)
    files["camera-intrinsics.txt"] = b"10 0 3.5\n0 0 1\n0 10 2.5\n"  # fy = 0: the message named no file before
    assert run(files) == "error"
    files = layout("tum", 1)
    files["camera.yaml"] = b"\x89PNG"  # a UnicodeDecodeError without the file's name before
    assert run(files) == "error"


def test_image_size_is_never_rounded():
    files = layout("tum", 1)
    files["camera.yaml"] = yaml.safe_dump(dict(CAMERA, width=8.5)).encode()  # silently 8 before
    assert run(files) == "error"
    files["camera.yaml"] = yaml.safe_dump(dict(CAMERA, fx=True)).encode()  # silently 1.0 before
    assert run(files) == "error"
