"""Fuzzing the config loader: generated YAML (real and unknown keys, values of every type and size), its bytes
mutated, random bytes, deep nesting and alias bombs.

Property: ``load_config`` returns a config or raises :class:`ConfigError` naming the file. A config that loads is
what the file says (every value in the file is the value in the config: nothing silently corrected) and is usable
by every stage (the extraction, mapping, matching and live-loop parameters all build from it).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import yaml
from hypothesis import given
from hypothesis import strategies as st

from reloc.config import Config, ConfigError, load_config
from reloc.extraction.params import ExtractionParams
from reloc.live.params import LiveParams
from reloc.mapping.builder import MappingParams
from reloc.matching.params import MatchingParams
from test_fuzz_common import Target, fuzz_settings, outcome

SECTIONS = {name: list(f.annotation.model_fields) for name, f in Config.model_fields.items()}

scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(-5, 100), st.integers(-(2**70), 2**70),
    st.floats(-10, 10), st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 1e308, -1e-300]),
    st.text(max_size=8), st.sampled_from(["camera_y", "kinect", "ray", "DEFAULT", "left", "", "yes", "0.5"]),
)
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                         st.dictionaries(st.text(max_size=5), inner, max_size=3)),
                      max_leaves=20)


@st.composite
def config_docs(draw) -> dict:
    """A mapping of sections, mostly with real keys, with values of any type."""
    doc = {}
    for _ in range(draw(st.integers(0, 4))):
        section = draw(st.one_of(st.sampled_from(sorted(SECTIONS)), st.text(max_size=6)))
        fields = SECTIONS.get(section, ["x"])
        body = {}
        for _ in range(draw(st.integers(0, 5))):
            key = draw(st.one_of(st.sampled_from(fields), st.sampled_from(fields), st.text(max_size=6)))
            body[key] = draw(values)
        doc[section] = draw(st.one_of(st.just(body), st.just(body), values))
    return doc


def _mutate(text: bytes, draw) -> bytes:
    kind = draw(st.integers(0, 5))
    b = bytearray(text)
    if kind == 0 or not b:  # as generated
        return bytes(b)
    i = draw(st.integers(0, len(b) - 1))
    if kind == 1:  # truncated
        return bytes(b[:i])
    if kind == 2:  # a byte replaced (non-UTF-8, control characters, YAML syntax)
        b[i] = draw(st.integers(0, 255))
        return bytes(b)
    if kind == 3:  # a line repeated (duplicate keys)
        lines = bytes(b).splitlines(keepends=True)
        j = draw(st.integers(0, len(lines) - 1))
        return b"".join(lines[: j + 1] + [lines[j]] + lines[j + 1:])
    if kind == 4:  # random bytes inserted
        return bytes(b[:i]) + draw(st.binary(min_size=1, max_size=8)) + bytes(b[i:])
    return bytes(b[:i]) + b"\n" + bytes(b[i:])  # a line broken


@st.composite
def config_files(draw) -> bytes:
    kind = draw(st.integers(0, 9))
    if kind <= 6:
        doc = draw(config_docs())
        flow = draw(st.booleans())
        return _mutate(yaml.safe_dump(doc, default_flow_style=flow, allow_unicode=True).encode(), draw)
    if kind == 7:
        return draw(st.binary(max_size=300))
    if kind == 8:  # deep nesting
        n = draw(st.integers(1, 2000))
        opener, closer = draw(st.sampled_from([("[", "]"), ("{a: ", "}"), ("- ", "")]))
        if opener == "- ":
            return "".join(" " * k + "- \n" for k in range(min(n, 400))).encode()
        return (opener * n + "1" + closer * n).encode()
    # An alias bomb: each level repeats the previous one ten times.
    levels = draw(st.integers(1, 12))
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]" for k in range(1, levels)]
    if draw(st.booleans()):
        lines.append(f"camera:\n  T_base_cam: *a{levels - 1}")
    return "\n".join(lines).encode()


def _same(a, b) -> bool:
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return isinstance(a, bool) == isinstance(b, bool) and isinstance(a, str) == isinstance(b, str) and a == b


def check_config(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fuzzed.yaml"
        path.write_bytes(data)
        cfg = load_config(path)
    # Nothing silently corrected: each value the file sets is the config's value, with its type.
    doc = yaml.safe_load(data.decode("utf-8")) or {}
    for section, body in doc.items():
        for key, value in (body or {}).items():  # a null section: its defaults
            got = getattr(getattr(cfg, section), key)
            assert _same(got, value), f"{section}.{key}: file says {value!r}, config holds {got!r}"
    # Usable by every stage.
    ExtractionParams.from_config(cfg)
    MatchingParams.from_config(cfg)
    MappingParams.from_config(cfg)
    LiveParams.from_config(cfg)


def run(data: bytes) -> str:
    return outcome(lambda: check_config(data), names="fuzzed.yaml", clear=(ConfigError,))


TARGET = Target("config", "config file (YAML)", config_files(), run)


@fuzz_settings(100)
@given(config_files())
def test_fuzzed_config_files_load_or_raise_config_error(data):
    run(data)


@fuzz_settings(60)
@given(config_docs())
def test_generated_config_documents_load_exactly_or_raise_config_error(doc):
    run(yaml.safe_dump(doc).encode())


# Regressions found by the fuzzer (each escaped before its fix).


def test_deeply_nested_yaml_is_a_config_error(tmp_path):
    p = tmp_path / "deep.yaml"
    p.write_text("[" * 5000 + "]" * 5000)  # RecursionError from the YAML composer before
    assert outcome(lambda: load_config(p), names="deep.yaml", clear=(ConfigError,)) == "error"


def test_alias_bomb_is_reported_in_linear_time(tmp_path):
    # 10^9 leaves when expanded; the duplicate-key walk followed every alias (minutes) before.
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]" for k in range(1, 9)]
    lines.append("camera:\n  T_base_cam: *a8")
    p = tmp_path / "bomb.yaml"
    p.write_text("\n".join(lines))
    assert outcome(lambda: load_config(p), names="bomb.yaml", clear=(ConfigError,), timeout_s=5) == "error"


def test_non_finite_huge_and_empty_values_are_config_errors(tmp_path):
    # Each loaded before and failed later (LiveParams), or overflowed the kernels' int64, or was an empty list of
    # reconnect waits (an IndexError in the reconnect loop).
    for text, path in [
        ("live:\n  reloc_period_s: .inf\n", "live.reloc_period_s"),
        ("extraction:\n  alpha: .nan\n", "extraction.alpha"),
        ("serial:\n  reconnect_backoff_s: []\n", "serial.reconnect_backoff_s"),
        ("oak:\n  reconnect_backoff_s: [0.5, -1]\n", "oak.reconnect_backoff_s.1"),
        ("extraction:\n  min_points_per_voxel: 100000000000000000000\n", "extraction.min_points_per_voxel"),
    ]:
        p = tmp_path / "c.yaml"
        p.write_text(text)
        try:
            load_config(p)
        except ConfigError as exc:
            assert any(problem.startswith(path) for problem in exc.problems), exc.problems
        else:
            raise AssertionError(f"{text!r} loaded")
