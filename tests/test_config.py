"""Config loading: defaults from the paper, and every problem reported with its exact path, all at once."""

from __future__ import annotations

import numpy as np
import pytest

from reloc.cli import main as cli_main
from reloc.config import Config, ConfigError, config_from_dict, dump_config, load_config


def write(tmp_path, text: str | bytes, name: str = "c.yaml"):
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


def test_paper_defaults():
    cfg = Config()
    assert cfg.evaluation.min_matched_planes == 5  # tau_m
    assert (cfg.matching.triplet_min_angle_deg, cfg.matching.triplet_max_angle_deg) == (40.0, 140.0)
    assert cfg.matching.initial_planes == 5
    T = np.array(cfg.camera.T_base_cam).reshape(4, 4)
    # The camera looks along base x; its y (down) is base -z.
    np.testing.assert_allclose(T[:3, 2], [1, 0, 0])
    np.testing.assert_allclose(T[:3, 1], [0, 0, -1])


def test_config_is_frozen():
    cfg = Config()
    with pytest.raises(Exception):
        cfg.extraction.voxel_size_m = 1.0  # type: ignore[misc]


def test_empty_file_gives_defaults(tmp_path):
    assert load_config(write(tmp_path, "")) == Config()


def test_a_section_with_every_key_commented_out_takes_its_defaults(tmp_path):
    """``extraction:`` with its keys commented out is YAML's null; it was refused ("Input should be a valid
    dictionary"), though an empty file is valid. An unknown section is still named, whatever its value."""
    p = tmp_path / "c.yaml"
    p.write_text("extraction:\n  # voxel_size_m: 0.2\nmatching:\n  initial_planes: 6\n")
    cfg = load_config(p)
    assert cfg.extraction == Config().extraction and cfg.matching.initial_planes == 6
    p.write_text("extractoin:\n")
    with pytest.raises(ConfigError, match="extractoin"):
        load_config(p)


def test_dump_round_trips(tmp_path):
    p = write(tmp_path, dump_config())
    assert load_config(p) == Config()
    p2 = write(tmp_path, dump_config(comments=False), "plain.yaml")
    assert load_config(p2) == Config()


def test_a_number_written_with_an_exponent_and_no_point_is_a_number(tmp_path):
    """YAML 1.2 reads ``2e-3`` as a number; PyYAML (YAML 1.1) read it as text and the config was refused ("Input
    should be a valid number, got '2e-3'"). A word that only looks like one stays text, and is refused as such."""
    cfg = load_config(write(tmp_path, "extraction:\n  noise_coeff: 2e-3\n  irls_kernel_sigmas: 25E-1\n"))
    assert cfg.extraction.noise_coeff == 0.002 and cfg.extraction.irls_kernel_sigmas == 2.5
    with pytest.raises(ConfigError, match=r"extraction.noise_coeff: .*'2e'"):
        load_config(write(tmp_path, "extraction:\n  noise_coeff: 2e\n"))


def test_every_problem_reported_with_its_path(tmp_path):
    text = """
extraction:
  voxel_size_m: -1
  bogus_key: 3
  adaptive_weights: "yes"
matching:
  initial_planes: "5"
  triplet_min_angle_deg: 100
camera:
  min_depth_m: 5
  max_depth_m: 1
unknown_section: {}
"""
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text))
    problems = info.value.problems
    joined = "\n".join(problems)
    expected_paths = [
        "extraction.voxel_size_m:",
        "extraction.bogus_key: unknown key",
        "extraction.adaptive_weights:",
        "matching.initial_planes:",
        "matching.triplet_min_angle_deg:",
        "camera.max_depth_m: must be > min_depth_m",
        "unknown_section: unknown key",
    ]
    for path in expected_paths:
        assert any(p.startswith(path) for p in problems), f"{path!r} missing from:\n{joined}"
    assert len(problems) == len(expected_paths)
    assert "got -1" in joined and "got '5'" in joined


def test_duplicate_keys_are_reported_with_other_problems(tmp_path):
    text = "extraction:\n  voxel_size_m: 0.2\n  voxel_size_m: 0.3\nmerging:\n  enabled: 1\n"
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text))
    problems = info.value.problems
    assert problems[0].startswith("extraction.voxel_size_m: duplicate key (first at line 2, again at line 3)")
    assert any(p.startswith("merging.enabled:") for p in problems)


@pytest.mark.parametrize(
    "content, message",
    [
        (b"\xff\xfe\x00garbage", "not UTF-8"),
        ("extraction: [1, 2\n", "not valid YAML"),
        ("- a\n- b\n", "expected a mapping of sections"),
    ],
)
def test_unreadable_files(tmp_path, content, message):
    with pytest.raises(ConfigError, match=message):
        load_config(write(tmp_path, content))


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read the file"):
        load_config(tmp_path / "nope.yaml")


def test_strict_types_do_not_coerce():
    with pytest.raises(ConfigError, match="serial.baudrate"):
        config_from_dict({"serial": {"baudrate": 9600.5}})
    # An int where a float is expected is not a correction.
    assert config_from_dict({"extraction": {"voxel_size_m": 1}}).extraction.voxel_size_m == 1.0


def test_explained_fractions_must_not_exceed_the_acceptance_fraction():
    with pytest.raises(ConfigError, match="evaluation.*min_explained_known_fraction: must be <= min_explained_fraction"):
        config_from_dict({"evaluation": {"min_explained_fraction": 0.65}})
    cfg = config_from_dict({"evaluation": {"min_explained_fraction": 0.65, "min_explained_known_fraction": 0.5}})
    assert cfg.evaluation.min_explained_known_fraction == 0.5


def test_T_base_cam_is_checked():
    with pytest.raises(ConfigError, match="camera.T_base_cam: expected 16 numbers"):
        config_from_dict({"camera": {"T_base_cam": [1, 2, 3]}})
    with pytest.raises(ConfigError, match="rotation block"):
        config_from_dict({"camera": {"T_base_cam": [2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}})


def test_cli_config_commands(tmp_path, capsys):
    assert cli_main(["config", "dump"]) == 0
    out = capsys.readouterr().out
    assert "min_matched_planes: 5" in out
    good = write(tmp_path, out, "good.yaml")
    assert cli_main(["config", "check", str(good)]) == 0
    bad = write(tmp_path, "extraction:\n  voxel_size_m: 0\n", "bad.yaml")
    with pytest.raises(SystemExit) as info:
        cli_main(["config", "check", str(bad)])
    assert info.value.code == 1
    assert "extraction.voxel_size_m" in capsys.readouterr().err


def test_a_cameras_stereo_law_is_taken_with_its_layer_merge_and_the_note_says_so():
    from reloc.config import with_noise_law
    from reloc.extraction import ExtractionParams

    cfg, note = with_noise_law(Config(), ("stereo", 2.4e-3), "the camera")
    params = ExtractionParams.from_config(cfg)
    assert (params.noise_model, params.noise_coeff, params.layer_share) == ("stereo", 2.4e-3, 0.5)
    assert note.startswith("depth noise: stereo, sigma = 0.0024 z^2 m, from the camera")
    assert "merging.layer_min_shared: 0 stops it" in note
    # A config that sets the share keeps it, and the note does not claim the merge.
    own = config_from_dict({"merging": {"layer_min_shared": 0.0}})
    cfg, note = with_noise_law(own, ("stereo", 2.4e-3), "the camera")
    assert ExtractionParams.from_config(cfg).layer_share == 0.0 and "layer" not in note
    cfg, note = with_noise_law(Config(), ("tof", 2e-3), "the recording")
    assert ExtractionParams.from_config(cfg).layer_share == 0.0 and "layer" not in note
