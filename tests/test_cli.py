"""The `solidkit` command: groups listed, usage errors are one line (no traceback)."""

import subprocess
import sys

import pytest


def run(*args):
    return subprocess.run([sys.executable, "-m", "solidkit.cli", *args], capture_output=True, text=True, timeout=300)


def test_help_lists_groups():
    res = run("--help")
    assert res.returncode == 0
    for group in ("envmap", "capture", "ingest", "demo"):
        assert group in res.stdout


@pytest.mark.parametrize("args", [("envmap", "sun", "x.exr", "--bogus"), ("envmap", "rotate")])
def test_usage_errors_are_one_line(args):
    res = run(*args)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr + res.stdout
