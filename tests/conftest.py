"""Shared fixtures: the real-data folder (tests marked ``real`` skip cleanly without it)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = (REPO / ".." / "shared" / "data" / "real").resolve()
ASSETS = REPO / "solidkit" / "assets"


@pytest.fixture
def real_data() -> Path:
    """Path to ../shared/data/real; skips the test when the folder is absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real data not present at {REAL_DATA}")
    return REAL_DATA
