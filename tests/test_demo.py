"""The README's main job (`make demo`): the pipeline driver (solidkit.demo)."""

from __future__ import annotations

import json

import pytest

from solidkit.demo import DemoConfig, run_demo
from solidkit.errors import InputError


def test_demo_refuses_a_missing_card_before_writing_anything(tmp_path):
    with pytest.raises(InputError, match="card folder not found"):
        run_demo(tmp_path / "out", DemoConfig(card=tmp_path / "nope"), log=lambda s: None)
    assert not (tmp_path / "out").exists()


def test_a_failed_step_is_reported_and_the_steps_that_need_it_are_skipped(tmp_path):
    (tmp_path / "card").mkdir()
    lines: list[str] = []
    summary = run_demo(tmp_path / "out", DemoConfig(card=tmp_path / "card"), log=lines.append)
    status = [s["status"] for s in summary["steps"]]
    assert status == ["failed"] + ["skipped"] * 6
    assert "no captures" in summary["steps"][0]["note"]
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["steps"][0]["status"] == "failed"
    page = (tmp_path / "out" / "report.html").read_text()
    assert "<table>" in page and "skipped" in page
    assert any(line.startswith("[1/7]") for line in lines) and lines[-1].startswith("report:")
