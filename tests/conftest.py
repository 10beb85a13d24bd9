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


@pytest.fixture
def cli(monkeypatch, capsys):
    """Run ``solidkit ARGS`` in-process through the real entry point (``solidkit.cli.main``, with
    its error handling, without a subprocess's start-up cost): returns ``(exit code, stdout, stderr)``."""
    import sys

    from solidkit.cli import main

    def run(*args) -> tuple[int, str, str]:
        monkeypatch.setattr(sys, "argv", ["solidkit", *map(str, args)])
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = int(exc.code or 0)
        out = capsys.readouterr()
        return code, out.out, out.err

    return run
