"""Evaluation and k-fold fine-tuning on hand-made items (solidkit.finetune.evaluate / finetune)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from solidkit import metrics as M
from solidkit.envmap.coords import direction_from_angles, direction_grid
from solidkit.envmap.io import srgb_decode
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.errors import InputError
from solidkit.finetune.evaluate import EvalItem, ItemPrediction, MeanBaseline, Method, evaluate
from solidkit.finetune.finetune import FineTuneConfig, local_ldr_loss, run_finetune, scene_folds
from solidkit.model.config import preset
from solidkit.model.solidnet import SolidNet

H = 128


def _world(az: float, el: float, seed: int) -> np.ndarray:
    d = direction_grid(H)
    sun = np.asarray(direction_from_angles(math.radians(az), math.radians(el)))
    up = -d[..., 1]
    rng = np.random.default_rng(seed)
    ground = 0.05 + 0.03 * np.sin(7 * np.arctan2(d[..., 0], d[..., 2]) + rng.uniform(0, 6))
    sky = np.where(up > 0, 0.3 + 0.4 * up, ground) + 2e3 * (d @ sun > math.cos(math.radians(2.0)))
    return (sky[..., None] * np.array([0.85, 0.9, 1.0])).astype(np.float32)


def _item(scene: str, az: float = 30.0, el: float = 40.0, n: int = 2, seed: int = 0) -> EvalItem:
    rng = np.random.default_rng(seed)
    world = _world(az, el, seed)
    probes = [M.simulate_ldr_probe(world * (1 + 0.1 * k)) for k in range(n)]
    return EvalItem(
        scene=scene,
        id=scene,
        image=rng.uniform(0, 1, (240, 320, 3)).astype(np.float32),
        K=intrinsics_from_fov(math.radians(60.0), 320, 240),
        pitch=0.0,
        roll=0.0,
        pixels=np.array([[80.0 + 100 * k, 200.0] for k in range(n)]),
        probe_ids=[f"p{k}" for k in range(n)],
        sun=np.asarray(direction_from_angles(math.radians(az), math.radians(el))),
        global_hdr=world,
        probes_ldr=[p[0] for p in probes],
        probes_saturated=[p[1] for p in probes],
        probes_hdr=[None] * n,
        source="real",
    )


class Oracle(Method):
    """Predicts the truth (the probe linearised, the true global map): what a perfect model scores."""

    name = "oracle"

    def predict(self, item):
        return ItemPrediction(item.global_hdr, [srgb_decode(p) * 3.0 for p in item.probes_ldr])


def test_scene_folds_never_leak_a_scene_and_test_each_once():
    scenes = [f"s{i}" for i in range(11)] + ["s3", "s3"]  # repeated ids: one scene, several items
    folds = scene_folds(scenes, 4, seed=5)
    assert len(folds) == 4
    tested = [s for f in folds for s in f["test"]]
    assert sorted(tested) == sorted(set(scenes))
    for f in folds:
        assert not set(f["test"]) & (set(f["train"]) | set(f["val"]))
        assert not set(f["train"]) & set(f["val"])
        assert set(f["train"]) | set(f["val"]) | set(f["test"]) == set(scenes)
        assert f["val"]
    assert scene_folds(scenes, 4, seed=5) == folds
    assert scene_folds(scenes, 4, seed=6) != folds
    assert len(scene_folds(["a", "b"], 5)) == 2  # k capped at the number of scenes
    with pytest.raises(InputError):
        scene_folds(["a", "a"], 2)


def test_oracle_scores_perfectly_and_mean_probe_is_leave_one_scene_out():
    items = [_item("a", 30, 40, seed=1), _item("b", -100, 20, seed=2), _item("c", 150, 60, seed=3)]
    mean = MeanBaseline("probe")
    res = evaluate(items, [Oracle(), mean])
    s = res["summary"]["oracle"]
    assert s["local_ssim"]["median"] > 0.999 and s["local_mae"]["median"] < 2e-3
    assert s["angle_deg/core"]["median"] < 1.0 and s["no_sun_rate/core"]["rate"] == 0.0
    assert s["global_mae"]["median"] == pytest.approx(0.0, abs=1e-6)
    # the mean probe predicted for "a" is made of "b" and "c" only
    only_bc = MeanBaseline("probe")
    only_bc.prepare(items[1:])
    assert np.allclose(mean.predict(items[0]).local[0], only_bc._mean_without("none"), atol=1e-6)
    assert res["summary"]["mean-probe"]["local_ssim"]["median"] < s["local_ssim"]["median"] - 0.05


def test_local_loss_is_exposure_invariant_ignores_saturation_and_vanishes_on_the_truth():
    it = _item("a", seed=4)
    probe = torch.as_tensor(np.stack(it.probes_ldr)).permute(0, 3, 1, 2)
    sat = torch.as_tensor(np.stack([M.saturation_mask(p, s) for p, s in zip(it.probes_ldr, it.probes_saturated)]))
    truth = srgb_decode(probe)
    assert float(local_ldr_loss(truth * 7.0, probe, sat)) < 0.02
    other = truth * torch.linspace(0.5, 2.0, truth.shape[-1])  # a wrong prediction
    base = float(local_ldr_loss(other, probe, sat))
    assert base > 0.1
    assert float(local_ldr_loss(other * 50.0, probe, sat)) == pytest.approx(base, rel=1e-3)
    hot = other.clone()
    hot[sat[:, None].expand_as(hot)] = 1e4  # anything where the probe is clipped
    assert float(local_ldr_loss(hot, probe, sat)) == pytest.approx(base, rel=1e-4)


def test_kfold_finetuning_runs_records_the_split_and_lowers_the_training_loss(torch_one_thread):
    torch.manual_seed(0)
    net = SolidNet(preset("tiny")).eval()
    items = [_item(s, az, 35, seed=i) for i, (s, az) in enumerate([("a", 20), ("b", -60), ("c", 100), ("d", 170)])]
    cfg = FineTuneConfig(folds=2, epochs=3, patience=5, lr=3e-3, seed=0)
    res = run_finetune(net, items, cfg)
    assert len(res["folds"]) == 2 and len(res["models"]) == 2
    for f in res["folds"]:
        split = f["split"]
        assert not set(split["test"]) & (set(split["train"]) | set(split["val"]))
        h = f["history"]
        assert h[0]["train"] is None  # no pass over the training photos before the first step
        assert h[-1]["train"] < h[1]["train"]  # it learns on the training scenes
        assert f["trainable_parameters"] < sum(p.numel() for p in net.parameters())
    # the fold's model never saw its test scenes: before/after records cover exactly them
    tested = sorted({r["scene"] for r in res["pooled"]["records"]})
    assert tested == ["a", "b", "c", "d"]
    assert set(res["effect"]) == {"local_ssim", "local_mae", "sun_angle/paper", "sun_angle/core"}
    # the original model is untouched (fine-tuning works on copies)
    assert all(p.requires_grad for p in net.parameters())


def test_a_fold_runs_one_loss_pass_per_training_step_and_validation_epoch(torch_one_thread, monkeypatch):
    from solidkit.finetune import finetune as ft

    calls = {"grad": 0, "no_grad": 0}
    real = ft.real_losses

    def counted(model, item, sun_weight=1.0):
        calls["grad" if torch.is_grad_enabled() else "no_grad"] += 1
        return real(model, item, sun_weight)

    monkeypatch.setattr(ft, "real_losses", counted)
    torch.manual_seed(0)
    net = SolidNet(preset("tiny")).eval()
    train = [_item(s, az, 35, seed=i) for i, (s, az) in enumerate([("a", 20), ("b", -60), ("c", 100)])]
    val = [_item("v", 50, 30, seed=9)]
    _, rec = ft.finetune_fold(net, train, val, FineTuneConfig(epochs=2, patience=5, seed=0))
    epochs = rec["epochs_run"]
    assert calls["grad"] == len(train) * epochs  # one training step per photo and epoch
    assert calls["no_grad"] == len(val) * (epochs + 1)  # validation before fine-tuning and after each epoch


def test_panorama_crops_carry_the_sun_into_each_photo_frame():
    from solidkit.envmap.coords import angles_from_direction
    from solidkit.finetune.evaluate import SHIPPED_PANORAMAS, items_from_panoramas

    items = items_from_panoramas([SHIPPED_PANORAMAS / "city.exr"], yaws=4, size=(64, 48), height=32)
    assert [i.id for i in items] == ["city@000", "city@090", "city@180", "city@270"]
    az = [math.degrees(float(angles_from_direction(i.sun)[0])) for i in items]
    # the panorama's sun (35.9° azimuth, tests/test_demo history) seen from photos turned by 0, 90, 180, 270°
    for k, a in enumerate(az):
        assert (a - (35.93 - 90 * k) + 180) % 360 - 180 == pytest.approx(0.0, abs=0.3)
    assert items[0].global_hdr.shape == (32, 64, 3) and items[0].image.shape == (48, 64, 3)


def test_panoramas_with_one_file_name_in_several_folders_are_separate_scenes(tmp_path):
    """Rendered sources are ``NNNNNN/scene.exr``: named by the stem alone they were one scene, and the
    leave-one-scene-out mean sky had nothing left to average."""
    from solidkit.finetune.evaluate import SHIPPED_PANORAMAS, MeanBaseline, items_from_panoramas

    paths = []
    for name in ("000000", "000001"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "scene.exr").symlink_to(SHIPPED_PANORAMAS / "city.exr")
        paths.append(tmp_path / name / "scene.exr")
    items = items_from_panoramas(paths, yaws=1, size=(64, 48), height=32)
    assert [i.scene for i in items] == ["000000/scene", "000001/scene"]
    mean = MeanBaseline("sky")
    mean.prepare(items)
    assert mean.predict(items[0]).sky is not None
