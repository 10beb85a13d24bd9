"""The campaign lock (solidkit.capture.lock): one writer at a time, named to the one refused; --wait queues."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from solidkit.capture.lock import LOCK_NAME, campaign_lock
from solidkit.errors import InputError
from solidkit.testset.build import build_testset
from tests.support.testset_campaign import edit_alignment, make_campaign

REPO = Path(__file__).resolve().parents[2]

ALIGN_THEN_HANG = """
import sys, time
from pathlib import Path
from solidkit.align.pipeline import align_campaign

def log(message):  # called inside the lock, before the first scene: say so, then hang there
    Path(sys.argv[2]).touch()
    time.sleep(60)

align_campaign(sys.argv[1], log=log)
"""

HOLD = """
import sys, time
from pathlib import Path
from solidkit.capture.lock import campaign_lock

with campaign_lock(sys.argv[1], "ingest"):
    Path(sys.argv[2]).touch()
    time.sleep(float(sys.argv[3]))
"""


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("lock") / "camp"
    make_campaign(root)
    return root


def _start(script: str, *args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", script, *map(str, args)], cwd=REPO, stderr=subprocess.PIPE)


def _wait_for(marker: Path, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not marker.exists():
        assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else proc.returncode
        assert time.monotonic() < deadline, "the other process never took the lock"
        time.sleep(0.02)


def test_build_and_a_second_align_refused_during_align(campaign, tmp_path, cli):
    """While an align runs (a real one, held inside its lock), `testset build` and a second `align`
    are refused with the running step, its pid and start time; nothing is written. After it: built."""
    marker = tmp_path / "aligning"
    proc = _start(ALIGN_THEN_HANG, campaign, marker)
    try:
        _wait_for(marker, proc)
        holder = json.loads((campaign / LOCK_NAME).read_text())
        assert holder["step"] == "align" and holder["pid"] == proc.pid
        for args in (
            ("testset", "build", campaign, "-o", tmp_path / "ts"),
            ("align", campaign),
            ("label", "sun", campaign),
            ("verify", campaign),
        ):
            code, out, err = cli(*args)
            line = " ".join(err.split())
            assert code == 2, (args, out, err)
            assert f"align (pid {proc.pid}, started {holder['started']}) is running on this campaign" in line, line
            assert "--wait" in line
        assert not (tmp_path / "ts").exists()
    finally:
        proc.kill()
        proc.wait()
    code, out, err = cli("testset", "build", campaign, "-o", tmp_path / "ts")  # the kernel released a killed holder
    assert code == 0, err
    assert (campaign / LOCK_NAME).read_text() == ""  # left as found


def test_wait_queues_behind_the_holder(campaign, tmp_path):
    marker = tmp_path / "held"
    proc = _start(HOLD, campaign, marker, 1.0)
    try:
        _wait_for(marker, proc)
        heard: list[str] = []
        t0 = time.monotonic()
        report = build_testset(campaign, tmp_path / "ts", wait=True, log=heard.append)
        waited = time.monotonic() - t0
    finally:
        proc.wait(timeout=30)
    assert report.scenes > 0 and proc.returncode == 0
    assert any(f"waiting for ingest (pid {proc.pid}" in h for h in heard), heard
    assert waited > 0.3  # it did wait for the holder (which held the lock for 1 s)


def test_a_killed_holders_record_names_no_one():
    """The record a killed process left is not taken for the holder (read before the new one wrote)."""
    from solidkit.capture.lock import holder_text

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    assert holder_text({"step": "align", "pid": dead.pid, "started": "x"}).startswith("another step")
    assert holder_text({"step": "align", "pid": os.getpid(), "started": "x"}).startswith(f"align (pid {os.getpid()}")


def test_the_lock_is_reentrant_and_left_as_found(tmp_path):
    camp = tmp_path / "camp"
    with campaign_lock(camp, "ingest"):
        before = (camp / LOCK_NAME).stat().st_mtime_ns
        with campaign_lock(camp, "align"):  # a step inside another, in the same process
            pass
        assert json.loads((camp / LOCK_NAME).read_text())["step"] == "ingest"
    assert (camp / LOCK_NAME).read_text() == ""
    assert (camp / LOCK_NAME).stat().st_mtime_ns <= before


def test_build_refuses_an_incomplete_or_older_alignment(tmp_path):
    camp = tmp_path / "camp"
    make_campaign(camp)
    data = json.loads((camp / "align" / "alignment.json").read_text())
    dropped = data["scenes"][-1]["id"]
    edit_alignment(camp, lambda d: d["scenes"].pop())  # an align interrupted, or run with --scene
    with pytest.raises(InputError, match=f"lacks 1 of the campaign's {len(data['scenes'])} scenes \\({dropped}"):
        build_testset(camp, tmp_path / "ts")
    edit_alignment(camp, lambda d: d["scenes"].append(data["scenes"][-1]))
    manifest = camp / "manifest.json"
    manifest.write_text(manifest.read_text().replace('"cards": []', '"cards": ["/media/card2"]'))  # an ingest ran
    with pytest.raises(InputError, match="the alignment is older than the campaign's manifest"):
        build_testset(camp, tmp_path / "ts")
    assert not (tmp_path / "ts").exists()
