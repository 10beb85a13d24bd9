"""SOLID-Net on the synthetic generator's data: the paper's reprojection against rendered buffers,
probe centres against the generator's, and train -> checkpoint -> predict (renders one tiny sample, ~15 s)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def synth_root(tmp_path_factory):
    from solidkit.synth.dataset import generate
    from solidkit.synth.sample import SampleConfig

    root = tmp_path_factory.mktemp("synth")
    cfg = SampleConfig(
        width=80, height=60, spp=4, buffer_spp=4, env_height=32, env_spp=4, probe_height=32, probe_spp=4, candidates=2
    )
    generate(root, 1, seed=3, config=cfg)
    return root


def test_reprojection_and_probe_centres_match_the_generator(synth_root):
    from solidkit.envmap.perspective import pixel_rays
    from solidkit.model.fit import batch_from_synth
    from solidkit.model.warp import camera_rotation, points_from_plane_distance, warp_to_probes
    from solidkit.synth.dataset import SynthDataset

    torch.set_num_threads(1)
    ds = SynthDataset(synth_root)
    item = ds[0]
    b = batch_from_synth([item])
    P, valid = points_from_plane_distance(b["normal"], b["distance"], b["K"])
    geo = b["geometry_mask"]
    assert (valid | ~geo).all()
    depth_points = item["depth"][None] * pixel_rays(b["K"], 80, 60, torch, dtype=b["K"].dtype).movedim(-1, -3)
    err = (P - depth_points).norm(dim=1, keepdim=True)[geo]
    assert err.max() < 1e-3 * max(1.0, float(item["depth"].max()))
    _, mask, centres = warp_to_probes(
        item["hdr"][None], b["normal"], b["distance"], b["K"], b["pixels"], b["pitch"], b["roll"], 32, 0.10
    )
    rec = json.loads((synth_root / ds.entries[0]["dir"] / "sample.json").read_text())
    R = camera_rotation(b["pitch"], b["roll"])[0]
    for k, probe in enumerate(rec["probes"][:4]):
        point = R @ torch.tensor(probe["point_camera"], dtype=torch.float32)
        # the probe centre is the surface point 10 cm off along its normal, in the panorama frame
        assert abs(float((centres[0, k] - point).norm()) - 0.10) < 2e-3
    assert mask.sum() > 0


def test_train_checkpoint_predict_on_synth(synth_root, tmp_path):
    from solidkit.model.config import preset
    from solidkit.model.fit import train_on_synth
    from solidkit.model.solidnet import SolidNet

    cfg = preset("tiny", image_size=(60, 80), pano_height=32)
    card = train_on_synth(
        str(synth_root), str(tmp_path / "ck.pt"), cfg, steps=3, max_seconds=60, batch_size=1, probes=2, seed=1
    )
    assert card["steps"] == 3 and card["data"]["samples"] == 1
    model = SolidNet.from_checkpoint(tmp_path / "ck.pt")
    assert model.card["seed"] == 1 and model.config == cfg
    pred = model.predict(np.full((60, 80, 3), 0.4, np.float32), [(40.0, 50.0)])
    assert pred.sky.shape == (32, 64, 3) and np.isfinite(pred.local[0]).all()
