"""``solidkit train``: configuration errors, panorama-crop data, and a resumed run that takes exactly the
steps an uninterrupted one takes (tiny model, two small rendered-free panorama sources)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from solidkit.envmap import angular_distance, detect_sun, direction_from_angles
from solidkit.errors import InputError
from solidkit.model.sunhead import render_sun
from solidkit.model.trainer import Trainer, load_train_config
from solidkit.synth.panocrops import CropConfig, CropSampler, load_sources

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _sky(height: int, az_deg: float, el_deg: float, energy: float = 2.0) -> np.ndarray:
    """A gradient sky over grey ground with a sun (an analytic stand-in for a rendered source)."""
    from solidkit.envmap import direction_grid

    d = direction_grid(height)
    up = -d[..., 1]
    sky = np.stack([0.4 + 0.3 * up, 0.6 + 0.4 * up, 1.0 + 0.5 * up], -1)
    sky = np.where(up[..., None] > 0, sky, 0.25).astype(np.float32)
    sun_dir = torch.as_tensor(
        np.asarray(direction_from_angles(math.radians(az_deg), math.radians(el_deg))), dtype=torch.float32
    )
    sun = render_sun(sun_dir[None], torch.full((1, 3), energy), torch.tensor([math.radians(0.3)]), height)[0]
    return sky + sun.permute(1, 2, 0).numpy()


@pytest.fixture
def sources(tmp_path, write_sources) -> Path:
    return write_sources(
        tmp_path / "sources", [(_sky(256, az, el), _sky(128, az, el)) for az, el in ((30.0, 40.0), (-100.0, 20.0))]
    )


def test_crops_are_reproducible_and_their_sun_follows_the_yaw(sources):
    srcs = load_sources(sources)
    s = CropSampler(srcs, seed=4, config=CropConfig(flip=False))
    a, b = s(7), s(7)
    assert all(np.array_equal(a[k], b[k]) for k in ("image", "sky", "sun_dir"))
    assert a["image"].shape == (240, 320, 3) and a["sky"].shape == (128, 256, 3) and a["sun_visible"] == 1.0
    # the target is the source's lighting turned by -yaw: the sun's azimuth drops by the yaw
    src_sun = detect_sun(srcs[7 % 2].load()[1])
    want = np.asarray(direction_from_angles(src_sun.azimuth - float(a["yaw"]), src_sun.elevation))
    assert math.degrees(float(angular_distance(a["sun_dir"], want))) < 1.5


def test_flipped_crop_mirrors_the_sun():
    sky = _sky(128, 50.0, 30.0)
    from solidkit.synth.panocrops import Source

    src = Source("x", "real", None, _sky(256, 50.0, 30.0), sky)
    flips = [CropSampler([src], seed=1)(i) for i in range(12)]
    noflip = CropSampler([src], seed=1, config=CropConfig(flip=False))
    for i, it in enumerate(flips):
        ref = noflip(i)
        mirrored = ref["sun_dir"] * np.array([-1, 1, 1])
        assert np.allclose(it["sun_dir"], ref["sun_dir"], atol=1e-3) or np.allclose(it["sun_dir"], mirrored, atol=1e-3)
    assert any(not np.allclose(it["sun_dir"], noflip(i)["sun_dir"], atol=1e-3) for i, it in enumerate(flips))


def _config(tmp_path, sources, out, steps=4, **extra) -> Path:
    lines = [
        f'out = "{out}"',
        'model = "tiny"',
        f"seed = {extra.pop('seed', 5)}",
        f'crops = ["{sources}"]',
        f'val_crops = ["{sources}"]',
        "val_samples = 2",
        "val_every = 2",
        "log_every = 1",
        "checkpoint_every = 1",
        *[f"{k} = {json.dumps(v)}" for k, v in extra.items()],
        "[inet]",
        f"steps = {steps}",
        "batch_size = 2",
        "lr = 1e-3",
    ]
    path = tmp_path / f"{Path(out).name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_resumed_run_takes_the_same_steps_as_an_uninterrupted_one(tmp_path, sources):
    full = Trainer(load_train_config(_config(tmp_path, sources, tmp_path / "full")), progress=False)
    full.run()
    cfg = load_train_config(_config(tmp_path, sources, tmp_path / "cut"))
    part = Trainer(cfg, progress=False)
    part.cfg.inet.steps = 2  # stop after two steps (as a kill after the step-2 checkpoint would)
    part.run()
    assert part.state["step"] == 2 and (tmp_path / "cut" / "last.pt").is_file()
    resumed = Trainer(load_train_config(_config(tmp_path, sources, tmp_path / "cut")), progress=False)
    resumed.run()
    assert resumed.state["step"] == 4
    a, b = full.model.state_dict(), resumed.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a), [k for k in a if not torch.equal(a[k], b[k])][:3]
    rows = (tmp_path / "full" / "metrics.csv").read_text().splitlines()
    assert rows[0].startswith("time,stage,step") and any(",val," in r for r in rows)
    for name in ("model.pt", "best_inet.pt", "config.toml"):
        assert (tmp_path / "full" / name).is_file()
    from solidkit.model import SolidNet

    card = SolidNet.from_checkpoint(tmp_path / "full" / "model.pt").card
    assert card["samples_seen"] == 8 and card["seed"] == 5
    from solidkit.fsutil import sha256_file
    from solidkit.model.trainer import export_checkpoint

    doc = export_checkpoint(tmp_path / "full" / "model.pt", tmp_path / "ship" / "m.pt", {"metrics": {"x": 1}})
    on_disk = json.loads((tmp_path / "ship" / "m.card.json").read_text())
    assert on_disk["sha256"] == sha256_file(tmp_path / "ship" / "m.pt") == doc["sha256"]
    assert on_disk["card"]["metrics"] == {"x": 1} and on_disk["card"]["seed"] == 5


def test_config_errors_are_one_line(tmp_path, sources, cli):
    bad = tmp_path / "bad.toml"
    bad.write_text('crops = ["x"]\nlearning_rate = 3\n')
    with pytest.raises(InputError, match="unknown keys"):
        load_train_config(bad)
    bad.write_text("[inet]\nsteps = -1\n")
    with pytest.raises(InputError, match="steps >= 0"):
        load_train_config(bad)
    bad.write_text('crops = ["a", "b"]\ncrop_weights = [1.0]\n')
    with pytest.raises(InputError, match="one weight >= 0 per crops folder"):
        load_train_config(bad)
    bad.write_text('crops = ["a"]\ncrop_weights = [0.0]\n')
    with pytest.raises(InputError, match="crop_weights"):
        load_train_config(bad)
    bad.write_text("not toml = = 1")
    code, out, err = cli("train", bad)
    assert code == 2 and "not valid TOML" in err and len(err.strip().splitlines()) == 1
    code, out, err = cli("train", tmp_path / "missing.toml")
    assert code == 2 and "no such training configuration" in err
    other = _config(tmp_path, sources, tmp_path / "run", steps=1)
    code, out, err = cli("train", other, "--no-progress")
    assert code == 0 and "stage / step" in out and "done" in out  # the summary (--json: the state)
    changed = _config(tmp_path, sources, tmp_path / "run", steps=1, seed=6)
    code, out, err = cli("train", changed)
    assert code == 2 and "other settings (seed)" in err
    longer = _config(tmp_path, sources, tmp_path / "run", steps=2)  # a longer stage is allowed: resumes, goes on
    code, out, err = cli("train", longer, "--no-progress", "--json")
    assert code == 0 and json.loads(out.strip().splitlines()[-1])["step"] == 2 and "inet.steps" in err


@pytest.mark.slow
def test_torchrun_two_processes_share_each_batch(tmp_path, sources):
    """DDP on CPU (Gloo) through torchrun, never a home-made launcher: both ranks take half of every
    global batch; rank 0 alone writes the run folder."""
    import os
    import subprocess
    import sys

    cfg = _config(tmp_path, sources, tmp_path / "ddp", steps=2)
    torchrun = Path(sys.executable).with_name("torchrun")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run(
        [str(torchrun), "--nproc_per_node", "2", "-m", "solidkit.cli", "train", str(cfg), "--no-progress"],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    states = [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]
    assert len(states) == 2 and all(s["step"] == 2 and s["samples"] == 4 for s in states)  # 2 steps x global batch 2
    assert (tmp_path / "ddp" / "model.pt").is_file() and (tmp_path / "ddp" / "last.pt").is_file()


def test_a_run_is_not_resumed_with_another_model_configuration(tmp_path, sources):
    # the run's model configuration is stored with its state: a preset changed since (a newer solidkit) is refused
    Trainer(load_train_config(_config(tmp_path, sources, tmp_path / "run", steps=1)), progress=False).run()
    state = tmp_path / "run" / "last.pt"
    payload = torch.load(state, map_location="cpu", weights_only=True)
    stored = json.loads(payload["model_config"])
    assert stored["sky_footprint"] == "camera" and stored["exposure_key"] == 0.18
    payload["model_config"] = json.dumps({**stored, "sky_footprint": "level"})
    torch.save(payload, state)
    with pytest.raises(InputError, match="sky_footprint"):
        Trainer(load_train_config(_config(tmp_path, sources, tmp_path / "run", steps=2)), progress=False).run()
    # a state from before the configuration was stored resumes (with a note in the log)
    del payload["model_config"]
    torch.save(payload, state)
    lines: list[str] = []
    t = Trainer(
        load_train_config(_config(tmp_path, sources, tmp_path / "run", steps=2)), progress=False, log=lines.append
    )
    t.run()
    assert t.state["step"] == 2 and any("without its model configuration" in x for x in lines)


def test_folder_weights_are_shared_evenly_within_a_folder():
    from solidkit.model.trainer import _Data

    d = _Data(["a", "b"], [], [], 0, weights=[0.75, 0.25])
    d.source_folders = [0, 0, 0, 1]
    np.testing.assert_allclose(d.source_weights(), [0.25, 0.25, 0.25, 0.25])
    d.source_folders = [0, 1, 1, 1]
    np.testing.assert_allclose(d.source_weights(), [0.75, 0.25 / 3, 0.25 / 3, 0.25 / 3])
    assert _Data(["a"], [], [], 0).source_weights() is None


def test_frozen_parts_of_a_stage_do_not_move_and_the_rest_does(tmp_path, sources):
    path = _config(tmp_path, sources, tmp_path / "frozen", steps=2)
    path.write_text(path.read_text() + 'frozen = ["encoder", "decoders"]\n')
    tr = Trainer(load_train_config(path), progress=False)
    before = {k: v.clone() for k, v in tr.model.state_dict().items()}
    tr.run()
    after = tr.model.state_dict()
    moved = {k for k in before if not torch.equal(before[k], after[k])}
    assert moved and all(k.startswith(("inet.sky", "inet.light", "inet.sun")) for k in moved), sorted(moved)
    assert not any(k.startswith(("inet.encoder", "inet.decoders")) for k in moved)


def test_frozen_names_must_be_parts_of_the_stage(tmp_path, sources):
    path = _config(tmp_path, sources, tmp_path / "bad", steps=2)
    path.write_text(path.read_text() + 'frozen = ["encoder", "skyy"]\n')
    with pytest.raises(InputError, match=r"frozen names \['skyy'\]"):
        load_train_config(path)


def test_metered_samples_are_exposed_as_predict_exposes_a_photo():
    from solidkit.envmap.io import decode_ldr, tonemap
    from solidkit.model.trainer import _relight_item, sample_meter_gain
    from solidkit.synth.panocrops import METER_EPS

    rng = np.random.default_rng(0)
    hdr = torch.as_tensor(rng.uniform(0.002, 0.02, (3, 12, 16)), dtype=torch.float32)  # a dark render
    probes = torch.ones(2, 3, 8, 16)
    item = {"hdr": hdr, "image": tonemap(hdr).clamp(0, 1), "probes": probes}
    g = sample_meter_gain(item, 0.18)
    out = _relight_item(item, np.full(3, g))
    lin = decode_ldr(out["image"].numpy().transpose(1, 2, 0), "paper")
    y = lin @ np.asarray([0.2126, 0.7152, 0.0722], np.float32)
    assert math.exp(np.mean(np.log(METER_EPS + y))) == pytest.approx(0.18, rel=0.02)  # what predict would meter
    assert torch.allclose(out["probes"], probes * g)  # the light moves with the photo
    bright = {"hdr": torch.full((3, 4, 4), 1e4)}  # clipped pixels count at the clip level, not their radiance
    assert sample_meter_gain(bright, 0.18) == pytest.approx(
        0.18 / float(decode_ldr(np.ones((1, 1, 3)), "paper")[0, 0, 1]), rel=1e-3
    )
    assert sample_meter_gain({"image": item["image"]}, 0.18) == 1.0
