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
def write_sources():
    """``write(root, pairs)``: one crop-path source folder (``solidkit.synth.panocrops`` layout) per
    ``(scene, light)`` pair of panoramas under ``root``; returns ``root``."""
    import json

    def write(root: Path, pairs) -> Path:
        from solidkit.envmap import write_exr
        from solidkit.synth.panocrops import SOURCE_FILES

        for i, (scene, light) in enumerate(pairs):
            d = root / f"{i:06d}"
            d.mkdir(parents=True)
            write_exr(d / SOURCE_FILES["scene"], scene)
            write_exr(d / SOURCE_FILES["light"], light)
            (d / SOURCE_FILES["meta"]).write_text(json.dumps({"kind": "test"}))
        return root

    return write


def _entry_point(monkeypatch, capture):
    import sys

    from solidkit.cli import main

    def run(*args) -> tuple[int, str, str]:
        monkeypatch.setattr(sys, "argv", ["solidkit", *map(str, args)])
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = int(exc.code or 0)
        out = capture.readouterr()
        return code, out.out, out.err

    return run


@pytest.fixture
def cli(monkeypatch, capsys):
    """Run ``solidkit ARGS`` in-process through the real entry point (``solidkit.cli.main``, with
    its error handling, without a subprocess's start-up cost): returns ``(exit code, stdout, stderr)``."""
    return _entry_point(monkeypatch, capsys)


@pytest.fixture
def cli_fd(monkeypatch, capfd):
    """:func:`cli` with stdout and stderr as file descriptors 1 and 2 saw them (C libraries write there
    directly)."""
    monkeypatch.delenv("SOLIDKIT_DEBUG", raising=False)
    capfd.readouterr()
    return _entry_point(monkeypatch, capfd)
