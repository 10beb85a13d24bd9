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


@pytest.mark.slow  # the whole chain (ingest, align, test set, eval, k-fold) on the shipped campaign: ~1-3 min
def test_demo_end_to_end_on_the_shipped_campaign_is_held_against_its_truth(tmp_path, torch_one_thread):
    from solidkit.demo import MINI_CAMPAIGN

    assert (MINI_CAMPAIGN / "card").is_dir(), "the shipped mini campaign is missing"
    summary = run_demo(tmp_path / "out", DemoConfig(folds=2, epochs=1, grids=1), log=lambda s: None)
    steps = {s["name"]: s for s in summary["steps"]}
    assert [s["status"] for s in summary["steps"]] == ["ok"] * 7, [(s["name"], s["note"]) for s in summary["steps"]]
    truth = steps["truth check"]
    assert truth["sun_error_deg"]["max"] < 1.0  # automatic sun labels against the hidden truth
    assert truth["rotation_error_deg"]["median"] < 2.0 and truth["pixel_error_px"]["median"] < 6.0
    assert truth["sun_missed"] == 0 and truth["sun_false"] == 0
    ts = steps["build + validate test set"]
    assert ts["problems"] == 0 and ts["probes"] >= 2
    out = tmp_path / "out"
    page = (out / "report.html").read_text()
    for needle in ("The chain against the truth", "Fine-tuning: does it help?", "sun_cumulative.png"):
        assert needle in page
    assert len(list((out / "finetune").glob("fold_*.pt"))) == 2
    assert summary["seconds"] < 600
