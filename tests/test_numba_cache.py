"""The numba cache directory: NUMBA_CACHE_DIR wins, a read-only install falls back to the user cache directory, and
a cold cache is announced in one line (and only then)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from helpers import KERNEL_MODULES

from reloc import _numba


def test_numba_cache_dir_is_honoured(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert _numba.configure_cache_dir() == str(tmp_path / "mine")
    assert _numba.cache_location() == str(tmp_path / "mine")


def test_read_only_package_falls_back_to_the_user_cache(monkeypatch, tmp_path):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    real_access = os.access
    package = str(_numba._PACKAGE_ROOT / "reloc")
    monkeypatch.setattr(_numba.os, "access",
                        lambda p, mode: False if str(p) == package else real_access(p, mode))
    chosen = _numba.configure_cache_dir()
    expected = tmp_path / "xdg" / "voxelplane-reloc" / "numba"
    assert chosen == str(expected) and expected.is_dir()
    assert os.environ["NUMBA_CACHE_DIR"] == str(expected)  # set before numba reads it


def test_writable_package_keeps_numbas_default(monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(_numba.os, "access", lambda p, mode: True)
    assert _numba.configure_cache_dir() is None
    assert "NUMBA_CACHE_DIR" not in os.environ


def test_cold_cache_prints_one_line_and_warm_prints_none(monkeypatch, capsys):
    monkeypatch.setattr(_numba, "_WARMUPS", [])
    monkeypatch.setattr(_numba, "_KERNELS", [object(), object(), object()])
    monkeypatch.setattr(_numba, "_has_cache_index", lambda disp: disp is _numba._KERNELS[0])
    info = _numba.warm_up()
    err = capsys.readouterr().err
    assert info["kernels"] == 3 and info["cold"] == 2
    assert err.count("\n") == 1 and err.startswith("numba: compiling 2 kernels on a cold cache")
    monkeypatch.setattr(_numba, "_has_cache_index", lambda disp: True)
    assert _numba.warm_up()["cold"] == 0
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(_numba, "_has_cache_index", lambda disp: False)
    _numba.warm_up(quiet=True)
    assert capsys.readouterr().err == ""
    said = []
    _numba.warm_up(say=said.append)  # e.g. tqdm.write, to stay clear of a progress bar
    assert len(said) == 1 and said[0].startswith("numba: compiling 3 kernels")
    assert capsys.readouterr().err == ""


def test_after_the_warm_up_every_registered_kernel_is_cached():
    """Otherwise every start would announce a cold cache (an inlined helper, compiled only into its callers, once
    counted as one cold kernel on every run of the demo)."""
    _numba.warm_up(KERNEL_MODULES, quiet=True)
    cold = [f"{d.py_func.__module__}.{d.py_func.__name__}" for d in _numba._KERNELS if not _numba._has_cache_index(d)]
    assert cold == []
    assert _numba.warm_up(quiet=True)["cold"] == 0


def test_the_warm_up_calls_every_kernel_the_matcher_calls():
    """A kernel no warm-up calls compiles (or loads) inside the first timed query: the path test's kernel once added
    2.2 s to the first query of a recorded suite. In a fresh process, after the warm-up every kernel that the matcher's
    Python code calls (``K.name(`` in ``reloc/matching/*.py``) has a compiled signature."""
    import re

    root = Path(__file__).resolve().parent.parent / "reloc" / "matching"
    called = sorted({m for f in root.glob("*.py") for m in re.findall(r"\bK\.(\w+)\(", f.read_text())})
    assert "path_blocked" in called and "verify_transforms" in called
    code = ("from reloc import _numba\n"
            "from reloc.matching import _kernels as K\n"
            "_numba.warm_up(('reloc.matching._kernels',), quiet=True)\n"
            f"print([n for n in {called!r} if not getattr(K, n).signatures])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_a_fresh_process_uses_the_directory_it_is_given(tmp_path):
    """Set before import, NUMBA_CACHE_DIR is where numba itself puts the cache."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    out = subprocess.run(
        [sys.executable, "-c", "import reloc._numba, numba.core.config as c; print(c.CACHE_DIR)"],
        env=env, capture_output=True, text=True, timeout=120, check=True,
    ).stdout.strip()
    assert Path(out) == tmp_path / "cache"


def test_a_helper_takes_every_package_but_the_one_with_the_most_warm_ups():
    def fake(module):
        def fn():
            pass
        fn.__module__ = module
        return fn

    ext = [fake("reloc.extraction._kernels_fit"), fake("reloc.extraction._kernels_merge")]
    rest = [fake("reloc.matching._kernels"), fake("reloc.mapping._kernels"), fake("sim._render_kernels")]
    assert _numba._helper_share(ext + rest) == rest
    assert _numba._helper_share(ext) == []  # one package: nothing to share
    assert _numba._helper_share([]) == []


_PACKAGE_A = """
import numpy as np
from reloc._numba import njit, register_warmup

@njit
def {name}(x):
    s = 0.0
    for v in x:
        s += v * v
    return s

@register_warmup
def _warm_{name}():
    {name}(np.ones(3))
"""


def test_on_a_cold_cache_a_helper_compiles_its_share_and_this_process_loads_it(tmp_path):
    """Two packages with tiny kernels, in a fresh process on an empty cache: the helper compiles the smaller
    package's kernel (this process loads it from the cache: a hit, no miss), this process compiles the others."""
    if _numba._usable_cores() < 2:
        import pytest

        pytest.skip("one usable core: no helper process is started")
    for pkg, names in (("vp_small", ["small_k"]), ("vp_big", ["big_k1", "big_k2"])):
        (tmp_path / pkg).mkdir()
        (tmp_path / pkg / "__init__.py").write_text("")
        for n in names:
            (tmp_path / pkg / f"{n}.py").write_text(_PACKAGE_A.format(name=n))
    code = ("from reloc import _numba\n"
            "info = _numba.warm_up(('vp_small.small_k', 'vp_big.big_k1', 'vp_big.big_k2'), quiet=True)\n"
            "import vp_small.small_k as s, vp_big.big_k1 as b\n"
            "def st(d): return sum(d.stats.cache_hits.values()), sum(d.stats.cache_misses.values())\n"
            "print(info['helper'], info['cold'], st(s.small_k), st(b.big_k1))\n"
            "print(_numba.warm_up(quiet=True)['helper'])\n")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(Path(__file__).resolve().parent.parent)]))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.strip().splitlines()
    assert first == "True 3 (1, 0) (0, 1)"  # helper ran; small_k loaded (hit), big_k1 compiled here (miss)
    assert second == "False"  # warm now: no helper
    env.update(NUMBA_CACHE_DIR=str(tmp_path / "cache_off"), RELOC_NUMBA_HELPER="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[0] == "False 3 (0, 1) (0, 1)"  # switched off: all compiled here


def test_the_simulators_kernels_are_all_warmed_up_where_simulated_frames_are_timed():
    """``sim._noise_kernels`` is imported only when a frame is first made noisy, so a warm-up of ``sim.render`` left
    its compilation (1.7 s) inside the first timed phase: the demo's map, reloc_accuracy's prepare_s. Every kernel
    module of the simulator is in ``sim.KERNEL_MODULES``, and the demo and the benchmarks that simulate warm those."""
    import sim

    root = Path(__file__).resolve().parent.parent
    files = sorted(f"sim.{f.stem}" for f in (root / "sim").glob("_*kernels.py"))
    assert sorted(sim.KERNEL_MODULES) == files and "sim._noise_kernels" in files
    for path in ("reloc/demo.py", "benchmarks/reloc_accuracy.py", "benchmarks/reloc_latency.py",
                 "benchmarks/map_accuracy.py", "benchmarks/sim_speed.py"):
        text = (root / path).read_text()
        assert "*SIM_KERNELS" in text or "warm_up(SIM_KERNELS)" in text, path
        assert '"sim.render")' not in text, path
