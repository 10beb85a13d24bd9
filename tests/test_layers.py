"""The layer contracts in pyproject.toml ([tool.importlinter]), checked by import-linter's ``lint-imports``.

The first test checks the package as it is. The others break a temporary copy of the package on
purpose (an upward import, a cycle between siblings, typer in a domain module) and require
``lint-imports`` to fail and to name the offending import: a contract that cannot fail is no contract.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def lint(package_root: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` with the repository's contracts on the ``solidkit`` package found under ``package_root``."""
    env = {**os.environ, "PYTHONPATH": str(package_root), "COLUMNS": "200"}
    return subprocess.run(
        [str(LINT), str(ROOT / "pyproject.toml"), "--no-cache"],
        cwd=package_root,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_layers_kept():
    r = lint(ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "0 broken" in r.stdout


@pytest.fixture
def package_copy(tmp_path: Path) -> Path:
    shutil.copytree(
        ROOT / "solidkit",
        tmp_path / "solidkit",
        ignore=shutil.ignore_patterns("__pycache__", "*.pt", "*.exr", "*.png", "*.jpg", "*.JPG"),
    )
    return tmp_path


@pytest.mark.parametrize(
    "module, line, contract, expected",
    [
        # envmap is the bottom of the domain layers: importing capture from it runs upwards
        (
            "envmap/coords.py",
            "from solidkit.capture import frame_merge  # noqa",
            "layers",
            "solidkit.envmap.coords -> solidkit.capture.frame_merge",
        ),
        # an upward import hidden inside a function counts as much as one at module level
        (
            "calibration/profile.py",
            "def _lazy():\n    from solidkit.synth import scene  # noqa\n",
            "layers",
            "solidkit.calibration.profile -> solidkit.synth.scene",
        ),
        # a cycle inside one layer (the old synth.cameras <-> synth.sample)
        (
            "synth/cameras.py",
            "def _cycle():\n    from solidkit.synth.sample import Generator  # noqa\n",
            "acyclic",
            "No cycles are allowed in solidkit.synth",
        ),
        # typer belongs to solidkit.cli only
        ("camera/lens.py", "import typer  # noqa", "no-typer", "solidkit.camera.lens -> typer"),
    ],
)
def test_wrong_import_breaks_a_contract(package_copy: Path, module: str, line: str, contract: str, expected: str):
    path = package_copy / "solidkit" / module
    path.write_text(path.read_text() + "\n\n" + line + "\n")
    r = lint(package_copy)
    assert r.returncode == 1, r.stdout + r.stderr
    broken = r.stdout.split("Broken contracts", 1)[-1]
    assert expected in broken, r.stdout
    names = {"layers": "solidkit layers", "acyclic": "no import cycles", "no-typer": "only solidkit.cli speaks typer"}
    assert names[contract] in broken, r.stdout
    others = [n for c, n in names.items() if c != contract and c != "acyclic"]  # an upward import is also a cycle
    assert not any(n in broken for n in others), r.stdout
