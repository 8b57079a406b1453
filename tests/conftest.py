"""Shared fixtures. Real sensor clips live in ../shared/data/real beside the repository (or $RELOC_REAL_DATA)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
REAL_DATA = Path(os.environ.get("RELOC_REAL_DATA", REPO_ROOT.parent / "shared" / "data" / "real"))


@pytest.fixture(scope="session")
def real_data() -> Path:
    """Folder of the real depth clips; tests using it skip (with the reason) when it is absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real depth clips not found at {REAL_DATA} (set RELOC_REAL_DATA to their folder)")
    return REAL_DATA


# A run of this many tests or more compiles nearly every kernel; it warms them all up first (below).
WARM_UP_MIN_TESTS = 100


def pytest_collection_finish(session):
    """Before a run of the suite (WARM_UP_MIN_TESTS tests or more), every kernel is compiled or loaded at once.

    On a cold cache that is ``reloc._numba.warm_up``'s parallel compilation: a helper process compiles some packages'
    kernels while this process compiles the extraction's (63 s instead of 125 s on two cores, 2026-12-04), where the
    tests, one at a time, would compile them all in this process. On a warm cache it loads them, about a second.
    ``RELOC_TEST_WARM_UP=0`` leaves every kernel to compile when a test first calls it.
    """
    if (len(session.items) < WARM_UP_MIN_TESTS or session.config.option.collectonly
            or os.environ.get("RELOC_TEST_WARM_UP", "1") == "0"):
        return
    from helpers import KERNEL_MODULES

    from reloc._numba import warm_up

    warm_up(KERNEL_MODULES)
