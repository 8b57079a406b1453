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
