"""``reloc planes`` on a written simulated sequence and on a point cloud."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from reloc.cli import cli


def test_planes_command_on_a_sequence_and_a_cloud(tmp_path):
    sim = pytest.importorskip("sim")
    from sim.scenes import make_scene
    from sim.writer import write_sequence

    scene = make_scene("office")
    frames = sim.simulate_frames(scene=scene, n_frames=3, camera="kinect", width=160, height=120, seed=2)
    write_sequence(frames, scene, tmp_path / "seq")
    out = tmp_path / "out" / "planes.jsonl"
    res = CliRunner().invoke(cli, ["planes", str(tmp_path / "seq"), "--frames", "1:3", "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert [r["frame"] for r in lines] == [1, 2]
    for r in lines:
        assert r["planes"] and set(r["planes"][0]) == {"normal", "offset", "centroid", "count", "radius", "area"}
        assert abs(np.linalg.norm(r["planes"][0]["normal"]) - 1) < 1e-6
        assert {"backproject", "voxelize", "fit", "weight", "merge", "finalize", "total"} <= set(r["timings_ms"])
    assert (out.parent / "planes.config.yaml").is_file()
    # A range that selects no frame is an error (as for reloc map build and locate), and no file is left behind.
    empty = tmp_path / "empty.jsonl"
    res = CliRunner().invoke(cli, ["planes", str(tmp_path / "seq"), "--frames", "3:1", "-o", str(empty), "--quiet"])
    assert res.exit_code == 2 and "selects none" in res.output and not empty.exists()
    # A point cloud: a 2 x 2 m wall 3 m ahead, in its own frame.
    rng = np.random.default_rng(0)
    wall = np.column_stack([rng.uniform(-1, 1, 20000), rng.uniform(-1, 1, 20000), 3 + 0.002 * rng.normal(size=20000)])
    np.save(tmp_path / "wall.npy", wall.astype(np.float32))
    res = CliRunner().invoke(cli, ["planes", str(tmp_path / "wall.npy"), "-o", str(tmp_path / "wall.jsonl")])
    assert res.exit_code == 0, res.output
    (rec,) = [json.loads(x) for x in (tmp_path / "wall.jsonl").read_text().splitlines()]
    assert len(rec["planes"]) == 1
    p = rec["planes"][0]
    assert np.allclose(p["normal"], [0, 0, -1], atol=1e-3) and abs(p["offset"] - 3) < 2e-3
    assert p["count"] > 19000 and abs(p["area"] - 4.0) < 0.3
