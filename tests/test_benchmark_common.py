"""benchmarks/_common.py helpers that decide what a benchmark measures: the ``--set KEY=VALUE`` overrides."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from _common import parse_overrides  # noqa: E402


def test_overrides_parse_literals_and_keep_other_values_as_strings():
    got = parse_overrides(["bevel_max_width_voxels=3", "merge=False", " noise_model = stereo", "x=None",
                           "mounting_gravity_cam=(0, 1, 0)", "alpha= 0.5", "seed=1e3"])
    assert got == {"bevel_max_width_voxels": 3, "merge": False, "noise_model": "stereo", "x": None,
                   "mounting_gravity_cam": (0, 1, 0), "alpha": 0.5, "seed": 1000.0}
    assert parse_overrides([]) == {}
    assert parse_overrides(["a=1", "a=2"]) == {"a": 2}  # the last one wins


@pytest.mark.parametrize("item", ["no_equals", "=3", " =3"])
def test_an_override_without_a_key_or_value_is_refused_by_name(item):
    with pytest.raises(ValueError, match="--set: expected KEY=VALUE"):
        parse_overrides([item])
