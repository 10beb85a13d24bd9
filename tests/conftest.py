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


@pytest.fixture
def torch_one_thread():
    """Run a test with one torch thread: on the shared 2-core CI machine oversubscription stalls convolutions."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
