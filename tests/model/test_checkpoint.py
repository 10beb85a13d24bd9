"""Checkpoints (config + conventions version), SolidNet.predict and the `solidkit predict` command."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from solidkit.envmap.io import read_exr, write_ldr
from solidkit.envmap.sun import detect_sun
from solidkit.errors import ConventionsError, InputError, SolidkitError
from solidkit.model.config import SolidNetConfig, preset
from solidkit.model.fit import toy_batch
from solidkit.model.solidnet import (
    CHECKPOINT_FORMAT,
    CheckpointError,
    SolidNet,
    load_checkpoint,
    save_checkpoint,
)

pytestmark = pytest.mark.usefixtures("torch_one_thread")


@pytest.fixture
def tiny_ckpt(tmp_path):
    torch.manual_seed(0)
    model = SolidNet(preset("tiny"))
    path = save_checkpoint(model, tmp_path / "tiny.pt", {"data": "none", "steps": 0, "seed": 0})
    return model.eval(), path


def test_round_trip_gives_identical_outputs(tiny_ckpt):
    model, path = tiny_ckpt
    loaded = SolidNet.from_checkpoint(path)
    assert loaded.config == model.config and loaded.card["steps"] == 0
    b = toy_batch(model.config, 1, 2, 3)
    with torch.no_grad():
        a = model(b["image"], b["K"], b["pixels"], b["pitch"], b["roll"])
        c = loaded(b["image"], b["K"], b["pixels"], b["pitch"], b["roll"])
    for k in ("sky", "local", "albedo", "sh"):
        assert torch.equal(a[k], c[k])


def test_half_precision_checkpoint_is_smaller_and_close(tiny_ckpt, tmp_path):
    model, path = tiny_ckpt
    half = save_checkpoint(model, tmp_path / "half.pt", half=True)
    assert half.stat().st_size < 0.75 * path.stat().st_size
    loaded = SolidNet.from_checkpoint(half)
    assert all(p.dtype == torch.float32 for p in loaded.parameters())
    b = toy_batch(model.config, 1, 1, 2)
    with torch.no_grad():
        a = model.inet(b["image"])["sky_log"]
        c = loaded.inet(b["image"])["sky_log"]
    assert torch.allclose(a, c, rtol=0.02, atol=0.02)


def test_missing_shipped_checkpoint_message(monkeypatch, tmp_path):
    import solidkit.model.solidnet as sn

    monkeypatch.setattr(sn, "DEFAULT_CHECKPOINT", tmp_path / "none.pt")
    with pytest.raises(CheckpointError, match="no shipped checkpoint"):
        SolidNet.from_checkpoint()


def _rewrite(path, out, **changes):
    payload = torch.load(path, weights_only=True)
    payload.update(changes)
    torch.save(payload, out)
    return out


def test_mismatched_checkpoints_fail_clearly(tiny_ckpt, tmp_path):
    _, path = tiny_ckpt
    with pytest.raises(ConventionsError, match="conventions version 99"):
        load_checkpoint(_rewrite(path, tmp_path / "conv.pt", conventions_version=99))
    with pytest.raises(CheckpointError, match="format version"):
        load_checkpoint(_rewrite(path, tmp_path / "fmt.pt", format_version=7))
    with pytest.raises(CheckpointError, match="not a solidkit"):
        load_checkpoint(_rewrite(path, tmp_path / "foreign.pt", format="other"))
    cfg = preset("small").to_dict()  # weights of the tiny model under the small config
    with pytest.raises(CheckpointError, match="do not fit"):
        SolidNet.from_checkpoint(_rewrite(path, tmp_path / "cfg.pt", config=cfg))
    with pytest.raises(CheckpointError, match="invalid model configuration"):
        load_checkpoint(_rewrite(path, tmp_path / "badcfg.pt", config={**cfg, "widths": []}))
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="not a readable"):
        load_checkpoint(junk)
    with pytest.raises(CheckpointError, match="no such"):
        load_checkpoint(tmp_path / "missing.pt")
    assert issubclass(CheckpointError, SolidkitError) and CHECKPOINT_FORMAT


def test_predict_outputs_and_pixel_scaling(tiny_ckpt):
    model, _ = tiny_ckpt
    img = toy_batch(model.config, 1, 1, 4)["image"][0].permute(1, 2, 0).numpy()
    big = np.repeat(np.repeat(img, 2, axis=0), 2, axis=1)  # 640 x 480: K and pixels are scaled
    pred = model.predict(big, [(100.0, 400.0), (500, 380)], pitch=math.radians(3.0))
    assert pred.sky.shape == (128, 256, 3) and pred.sky.dtype == np.float32
    assert len(pred.local) == 2 and all(x.shape == (128, 256, 3) for x in pred.local)
    assert pred.centres.shape == (2, 3) and np.isfinite(pred.centres).all()
    assert pred.sun.to_json() == detect_sun(pred.sky, "core").to_json()  # the sun reported is its own sky's
    small = model.predict(img, [(49.75, 199.75)], pitch=math.radians(3.0))  # same point at half resolution
    assert np.allclose(small.centres[0], pred.centres[0], atol=0.2)
    with pytest.raises(InputError):
        model.predict(img, [(400.0, 10.0)])
    with pytest.raises(InputError):
        model.predict(img[..., 0], [(10.0, 10.0)])


def test_cli_predict_writes_exr_png_json(tiny_ckpt, tmp_path):
    from solidkit.cli import app

    _, path = tiny_ckpt
    photo = tmp_path / "photo.png"
    write_ldr(photo, toy_batch(preset("tiny"), 1, 1, 5)["image"][0].permute(1, 2, 0).numpy())
    out = tmp_path / "pred"
    res = CliRunner().invoke(
        app,
        [
            "predict",
            str(photo),
            "--at",
            "100,200",
            "--at",
            "250,190",
            "--out",
            str(out),
            "--checkpoint",
            str(path),
            "--pitch",
            "-2",
        ],
    )
    assert res.exit_code == 0, res.output
    for name in ("sky.exr", "sky.png", "local_00.exr", "local_00.png", "local_01.exr", "local_01.png"):
        assert (out / name).is_file(), name
    report = json.loads((out / "prediction.json").read_text())
    assert set(report["sun"]) == {"found", "azimuth_deg", "elevation_deg", "confidence"}
    assert [p["pixel"] for p in report["probes"]] == [[100.0, 200.0], [250.0, 190.0]]
    assert all(isinstance(p["geometry_valid"], bool) for p in report["probes"])
    sky, meta = read_exr(out / "sky.exr")
    assert sky.shape == (128, 256, 3) and meta["conventions_version"] == 1


def test_cli_bad_input_is_one_line_error(tiny_ckpt, tmp_path):
    _, path = tiny_ckpt
    photo = tmp_path / "photo.png"
    write_ldr(photo, np.full((24, 32, 3), 0.5, np.float32))
    cmd = [
        sys.executable,
        "-c",
        "from solidkit.cli import main; main()",
        "predict",
        str(photo),
        "--at",
        "12;3",
        "--out",
        str(tmp_path / "o"),
        "--checkpoint",
        str(path),
    ]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "X,Y" in res.stderr


def test_shipped_checkpoint_predicts_out_of_the_box():
    from solidkit.fsutil import sha256_file
    from solidkit.model.solidnet import DEFAULT_CHECKPOINT

    card = json.loads(DEFAULT_CHECKPOINT.with_suffix(".card.json").read_text())
    assert card["sha256"] == sha256_file(DEFAULT_CHECKPOINT)
    assert DEFAULT_CHECKPOINT.stat().st_size < 5_000_000
    model = SolidNet.from_checkpoint()
    # the card's config as written, newer fields at their defaults
    assert model.config == SolidNetConfig.from_dict(card["config"]) and model.num_parameters == card["parameters"]
    for key in ("data", "steps", "hardware", "seed"):
        assert key in model.card
    img = toy_batch(model.config, 1, 1, 6)["image"][0].permute(1, 2, 0).numpy()
    pred = model.predict(img, [(160.0, 200.0)])
    assert pred.sky.shape == (128, 256, 3) and np.isfinite(pred.sky).all() and (pred.sky >= 0).all()
    assert pred.local[0].shape == (128, 256, 3) and np.isfinite(pred.local[0]).all()
