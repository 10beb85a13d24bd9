"""`solidkit eval` and `solidkit finetune` on a built test set (the analytic campaign of
tests/support/testset_campaign.py, 4 scenes) with a tiny checkpoint: reports, figures, JSON, fold checkpoints."""

from __future__ import annotations

import json

import pytest
import torch

from solidkit.model.config import preset
from solidkit.model.solidnet import SolidNet
from solidkit.testset.build import build_testset, load_testset
from tests.support.testset_campaign import make_campaign

SCENES = {
    "sA": (
        35.0,
        40.0,
        -6.0,
        1.0,
        {"p01": (200.0, 420.0), "p02": (470.0, 395.0)},
        {"cam": -20.0, "p01": 70.0, "p02": -130.0},
    ),
    "sB": (None, 30.0, -3.0, -0.5, {"p01": (320.0, 430.0)}, {"cam": 10.0, "p01": 160.0}),
    "sC": (-120.0, 25.0, -4.0, 0.0, {"p01": (150.0, 440.0)}, {"cam": 40.0, "p01": -70.0}),
    "sD": (160.0, 55.0, -2.0, 0.5, {"p01": (300.0, 400.0)}, {"cam": 0.0, "p01": 90.0}),
}


@pytest.fixture(scope="module")
def testset(tmp_path_factory):
    root = tmp_path_factory.mktemp("evalcli")
    make_campaign(root / "campaign", SCENES)
    build_testset(root / "campaign", root / "testset")
    torch.manual_seed(0)
    SolidNet(preset("tiny")).save(root / "tiny.pt", {"what": "untrained tiny model (test)"})
    return root


def test_eval_writes_report_figures_and_json(testset, cli, torch_one_thread):
    out = testset / "report"
    code, stdout, err = cli(
        "eval", "--testset", testset / "testset", "--model", testset / "tiny.pt", "-o", out, "--json", "--grids", "1"
    )
    assert code == 0, err
    summary = json.loads(stdout)["real"]
    assert set(summary) == {"solidnet", "global-as-local", "mean-sky", "mean-probe"}
    s = summary["solidnet"]
    assert s["local_ssim"]["n"] == 5  # every probe of the 4 scenes
    assert s["no_sun_rate/paper"]["n"] == 3  # sB has no sun in its truth
    lo, hi = s["local_ssim"]["median_ci"]
    assert lo <= s["local_ssim"]["median"] <= hi
    page = (out / "report.html").read_text()
    for name in ("real_sun_cumulative.png", "real_sun_violins.png", "real_sA.png"):
        assert (out / "figures" / name).stat().st_size > 1000
        assert f"figures/{name}" in page
    assert not (out / "figures" / "real_sB.png").exists()  # --grids 1
    res = json.loads((out / "results.json").read_text())
    assert {r["scene"] for r in res["results"]["real"]["records"]} == set(SCENES)
    version = load_testset(testset / "testset").dataset_version
    assert res["testset"]["path"] == str(testset / "testset") and res["testset"]["dataset_version"] == version
    assert res["testset"]["valid"] and f"dataset version `{version}`, valid" in (out / "report.md").read_text()


def test_eval_and_finetune_refuse_an_invalid_test_set_unless_allowed(testset, cli, torch_one_thread, tmp_path):
    """A test set whose probe file was changed after the build fails validation: eval and finetune refuse it,
    naming the problem and --allow-invalid; eval --allow-invalid runs with a warning and records it."""
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(testset / "testset", bad)
    ts = load_testset(bad)
    probe = bad / ts.scenes[0].probes[0].ldr
    probe.chmod(0o644)
    probe.write_bytes(probe.read_bytes()[:-1] + b"\0")
    for cmd in (["eval", "-o", tmp_path / "r"], ["finetune", "-o", tmp_path / "f", "--folds", "2", "--epochs", "1"]):
        code, _, err = cli(*cmd, "--testset", bad, "--model", testset / "tiny.pt")
        assert code == 2 and "fails validation" in err and "--allow-invalid" in err, (cmd, err)
        assert not (tmp_path / cmd[2] / "results.json").exists() and not (tmp_path / cmd[2] / "finetune.json").exists()
    code, _, err = cli(
        "eval",
        "--testset",
        bad,
        "--model",
        testset / "tiny.pt",
        "-o",
        tmp_path / "r",
        "--limit",
        "1",
        "--grids",
        "0",
        "--allow-invalid",
    )
    assert code == 0 and "used anyway (--allow-invalid)" in err, err
    rec = json.loads((tmp_path / "r" / "results.json").read_text())["testset"]
    assert not rec["valid"] and rec["problems"] and rec["dataset_version"] == ts.dataset_version
    assert "**fails validation**" in (tmp_path / "r" / "report.md").read_text()


@pytest.mark.slow  # the k-fold loop itself is in the default suite (test_finetune.py); this adds the CLI and its files
def test_finetune_kfold_writes_split_report_and_fold_checkpoints(testset, cli, torch_one_thread):
    out = testset / "ft"
    code, stdout, err = cli(
        "finetune",
        "--testset",
        testset / "testset",
        "--model",
        testset / "tiny.pt",
        "-o",
        out,
        "--folds",
        "2",
        "--epochs",
        "1",
        "--json",
    )
    assert code == 0, err
    res = json.loads(stdout)
    assert len(res["folds"]) == 2
    tested = [s for f in res["folds"] for s in f["split"]["test"]]
    assert sorted(tested) == sorted(SCENES)
    for f in res["folds"]:
        assert not set(f["split"]["test"]) & set(f["split"]["train"] + f["split"]["val"])
    assert res["effect"]["local_ssim"]["verdict"].startswith("too few scenes")  # 4 scenes cannot support a verdict
    for i in (1, 2):
        m = SolidNet.from_checkpoint(out / f"fold_{i}.pt")
        assert m.card["finetune"]["split"] == res["folds"][i - 1]["split"]
    assert "does it help" in (out / "report.md").read_text()
    assert (out / "figures" / "finetune_loss.png").stat().st_size > 1000
