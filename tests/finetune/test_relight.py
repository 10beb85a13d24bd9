"""Relighting in the evaluation (solidkit.finetune.relight): scores per probe and method, summaries with
intervals, the truth's kind, the report's table and figure. Real renders (Mitsuba), tiny and few samples."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solidkit.envmap.coords import coords_from_direction, direction_from_angles, rotation_from_ypr
from solidkit.envmap.io import srgb_encode
from solidkit.envmap.resample import rotate
from solidkit.finetune.evaluate import EvalItem, GlobalAsLocal, ItemPrediction, Method, evaluate
from solidkit.finetune.relight import RelightSettings, relight_evaluation
from solidkit.finetune.report import evaluation_sections, metric_tables, relight_figure, relight_table

H = 32
TURN = np.asarray(rotation_from_ypr(0.0, 0.0, math.radians(90.0)))  # up-left -> up-right


def _probe() -> np.ndarray:
    pano = np.full((H, 2 * H, 3), 0.05, np.float32)
    x, y = coords_from_direction(np.asarray(direction_from_angles(math.radians(-90.0), math.radians(45.0))), H)
    pano[int(y) - 1 : int(y) + 2, int(x) - 1 : int(x) + 2] = 300.0
    return pano


class Truth(Method):
    """Predicts the true probe (and it as the global map)."""

    name = "truth-oracle"

    def predict(self, item: EvalItem) -> ItemPrediction:
        p = _probe()
        return ItemPrediction(p, [p] * len(item.pixels))


class Turned(Method):
    """Predicts the true probe turned by 90° about the forward axis: the sun on the other side."""

    name = "turned"
    kind = "baseline"

    def predict(self, item: EvalItem) -> ItemPrediction:
        return ItemPrediction(None, [rotate(_probe(), TURN, interp="nearest")] * len(item.pixels))


def _item(name: str, hdr: bool) -> EvalItem:
    probe = _probe()
    ldr = srgb_encode(np.clip(probe / 4.0, 0, 1)).astype(np.float32)
    return EvalItem(
        scene=name,
        id=name,
        image=np.full((72, 96, 3), 0.45, np.float32),
        K=np.array([[100.0, 0.0, 47.5], [0.0, 100.0, 35.5], [0.0, 0.0, 1.0]]),
        pitch=0.0,
        roll=0.0,
        pixels=np.array([[48.0, 60.0]]),
        probe_ids=["p01"],
        sun=None,
        global_hdr=None,
        probes_ldr=[ldr],
        probes_saturated=[ldr.max(axis=-1) >= 250 / 255],
        probes_hdr=[probe if hdr else None],
        source="real",
    )


@pytest.fixture(scope="module")
def relit():
    items = [_item("sA", True), _item("sB", False)]
    oracle = Truth()
    methods = [oracle, Turned(), GlobalAsLocal(oracle)]
    result = evaluate(items, methods)
    scenes = relight_evaluation(
        result, items, methods, RelightSettings(spp=4, size=32, objects=("diffuse_sphere",)), figures=1
    )
    return result, scenes


def test_the_truth_scores_zero_error_and_the_turned_sun_90_degrees(relit) -> None:
    """Against the HDR truth (scene sA) the oracle scores 0 / 1 / 0°, the turned sun ~90°; against the LDR
    truth (sB, no bracket: linearised, its sun clipped) even the oracle is off."""
    result, _ = relit
    entries = {(r["method"], r["scene"]): r["relight"][0] for r in result["records"] if "relight" in r}
    oracle, turned = entries[("truth-oracle", "sA")], entries[("turned", "sA")]
    assert oracle["truth"] == "hdr" and oracle["lit_by"] == "local probe"
    assert oracle["shading_angle_deg"] == pytest.approx(0.0, abs=1e-6)
    assert oracle["objects"]["diffuse_sphere"]["si_rmse"] == pytest.approx(0.0, abs=1e-7)
    assert oracle["objects"]["diffuse_sphere"]["ssim"] == pytest.approx(1.0, abs=1e-6)
    # the sun's 3x3 block spans the rows about 45°; the turn keeps it at its elevation: 90° within 2°
    assert turned["shading_angle_deg"] == pytest.approx(90.0, abs=2.0)
    assert turned["objects"]["diffuse_sphere"]["si_rmse"] > 0.2
    assert turned["objects"]["diffuse_sphere"]["ssim"] < 0.99
    ldr = entries[("truth-oracle", "sB")]
    assert ldr["truth"] == "ldr" and ldr["shading_angle_deg"] > 1.0 and ldr["objects"]["diffuse_sphere"]["si_rmse"] > 0
    assert ldr["truth_saturated_fraction"] > 0 and oracle["truth_saturated_fraction"] == 0.0  # the clipped sun
    s = result["summary"]["turned"]["relight_angle_deg"]  # summarised over both scenes, with an interval
    assert s["n"] == 2 and s["median_ci"][0] <= s["median"] <= s["median_ci"][1]
    info = result["relight"]
    assert info["truth"] == {"hdr": 1, "ldr": 1} and info["truth_with_saturated_pixels"] == 1
    assert info["spp"] == 4 and info["renders"] == 2 * 5 and info["seconds_per_object_median"] > 0
    assert 0 < info["noise_floor"]["si_rmse/diffuse_sphere"]["median"] < 1


def test_the_report_shows_the_relighting_table_and_figure_and_keeps_the_other_tables(relit, tmp_path) -> None:
    result, scenes = relit
    assert len(scenes) == 1 and set(scenes[0].panels) == {"prediction", "truth", "global"}
    assert scenes[0].names["global"] == "global-as-local (truth-oracle) (global map)"
    table = relight_table(result)
    assert "| truth-oracle | local probe |" in table and "| turned |" in table and "*noise floor*" in table
    assert "relit" not in metric_tables({"real": result})  # the relighting has its own section
    path = relight_figure(scenes[0], tmp_path / "relit.png", "sA")
    assert path.stat().st_size > 5000
    sections = dict(evaluation_sections({"real": result}, tmp_path, relit={"real": scenes}))
    assert (
        "figures/real_sA_relit.png" in sections["Relit objects"]
        and (tmp_path / "figures" / "real_sA_relit.png").is_file()
    )
    without = dict(evaluation_sections({"real": {k: v for k, v in result.items() if k != "relight"}}, tmp_path))
    assert "Relit objects" not in without


@pytest.mark.slow  # ~15 s: builds a test set, renders 2 probes x 6 lightings x 3 objects
def test_eval_relight_on_a_built_test_set(cli, torch_one_thread, tmp_path) -> None:
    """`solidkit eval --relight` end to end on a built test set (two scenes, HDR probes): the table in the report,
    the figure, the scores in results.json for the model and every baseline, the truth's kind and the timing."""
    import json

    import torch

    from solidkit.model.config import preset
    from solidkit.model.solidnet import SolidNet
    from solidkit.testset.build import build_testset
    from tests.support.testset_campaign import make_campaign

    scenes = {
        "sA": (35.0, 40.0, -6.0, 1.0, {"p01": (200.0, 420.0)}, {"cam": -20.0, "p01": 70.0}),
        "sB": (-120.0, 25.0, -4.0, 0.0, {"p01": (150.0, 440.0)}, {"cam": 40.0, "p01": -70.0}),
    }  # two scenes: the mean baselines leave one out
    make_campaign(tmp_path / "campaign", scenes)
    build_testset(tmp_path / "campaign", tmp_path / "testset")
    torch.manual_seed(0)
    SolidNet(preset("tiny")).save(tmp_path / "tiny.pt", {"what": "untrained tiny model (test)"})
    out = tmp_path / "report"
    code, stdout, err = cli(
        "eval", "--testset", tmp_path / "testset", "--model", tmp_path / "tiny.pt", "-o", out, "--json",
        "--relight", "--relight-spp", "4",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads(stdout)["real"]
    for method in ("solidnet", "global-as-local", "mean-sky", "mean-probe"):
        assert summary[method]["relight_angle_deg"]["n"] == 2, method
        assert summary[method]["relight_si_rmse/bunny"]["n"] == 2, method
    res = json.loads((out / "results.json").read_text())["results"]["real"]
    assert res["relight"]["truth"] == {"hdr": 2, "ldr": 0} and res["relight"]["renderer"]
    md = (out / "report.md").read_text()
    assert "## Relit objects" in md and "Render time per object" in md and "figures/real_sA_relit.png" in md
    assert (out / "figures" / "real_sA_relit.png").stat().st_size > 10000
