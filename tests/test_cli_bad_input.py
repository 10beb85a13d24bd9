"""Every ``solidkit`` command answers bad input with a one-line error: non-zero exit, no traceback,
no new files (no partial outputs), inputs untouched.

One module-scoped folder holds tiny bad inputs (missing, empty, truncated, text renamed to an image,
not a panorama, NaN/Inf pixels, bad JSON profiles); each case runs the real CLI in a subprocess with
that folder as working directory and compares the folder's listing before and after.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from solidkit.envmap.io import write_exr

# Each case: (id, argv with {d} = the bad-input folder, marks). Outputs always go under {d}.
# SLOW: cases that repeat a mechanism another case already covers (or load torch / Mitsuba); `make test-slow`.
SLOW = (pytest.mark.slow,)
GOOD_PANO = "{d}/pano.exr"
CASES: list[tuple[str, list[str], tuple]] = [
    # ---- envmap info / sun: the panorama readers
    ("info-missing", ["envmap", "info", "{d}/missing.exr"], ()),
    ("info-empty-exr", ["envmap", "info", "{d}/empty.exr"], ()),
    ("info-trunc-exr", ["envmap", "info", "{d}/trunc.exr"], ()),
    ("info-text-exr", ["envmap", "info", "{d}/text.exr"], ()),
    ("info-empty-jpg", ["envmap", "info", "{d}/empty.jpg"], SLOW),
    ("info-text-jpg", ["envmap", "info", "{d}/text.jpg"], ()),
    ("info-trunc-jpg", ["envmap", "info", "{d}/trunc.jpg"], ()),
    ("info-not-pano", ["envmap", "info", "{d}/photo.jpg"], ()),
    ("info-nan", ["envmap", "info", "{d}/nan.exr"], ()),
    ("info-inf", ["envmap", "info", "{d}/inf.exr"], SLOW),
    ("info-directory", ["envmap", "info", "{d}/sub"], ()),
    ("info-unknown-suffix", ["envmap", "info", "{d}/notes.txt"], SLOW),
    ("sun-nan", ["envmap", "sun", "{d}/nan.exr"], SLOW),
    ("sun-not-pano", ["envmap", "sun", "{d}/notpano.exr"], SLOW),
    ("sun-bad-method", ["envmap", "sun", GOOD_PANO, "--method", "best"], ()),
    # ---- envmap rotate / crop: outputs
    ("rotate-trunc-exr", ["envmap", "rotate", "{d}/trunc.exr", "{d}/new/out.exr"], SLOW),
    ("rotate-out-parent-is-file", ["envmap", "rotate", GOOD_PANO, "{d}/notes.txt/out.exr"], ()),
    ("rotate-out-unknown-suffix", ["envmap", "rotate", GOOD_PANO, "{d}/out.txt"], ()),
    ("rotate-out-is-input", ["envmap", "rotate", GOOD_PANO, GOOD_PANO, "--yaw", "10"], ()),
    ("rotate-out-is-dir", ["envmap", "rotate", GOOD_PANO, "{d}/sub"], SLOW),
    ("rotate-yaw-text", ["envmap", "rotate", GOOD_PANO, "{d}/out.exr", "--yaw", "ten"], ()),
    ("rotate-yaw-nan", ["envmap", "rotate", GOOD_PANO, "{d}/out.exr", "--yaw", "nan"], ()),
    ("crop-out-is-input", ["envmap", "crop", GOOD_PANO, GOOD_PANO, "--fov", "60", "--size", "8x6"], SLOW),
    ("crop-size-12x", ["envmap", "crop", GOOD_PANO, "{d}/c.png", "--fov", "60", "--size", "12x"], ()),
    ("crop-size-zero", ["envmap", "crop", GOOD_PANO, "{d}/c.png", "--fov", "60", "--size", "0x0"], SLOW),
    ("crop-size-huge", ["envmap", "crop", GOOD_PANO, "{d}/c.png", "--fov", "60", "--size", "99999999x99999999"], SLOW),
    ("crop-fov-180", ["envmap", "crop", GOOD_PANO, "{d}/c.png", "--fov", "180", "--size", "8x6"], ()),
    ("crop-fov-negative", ["envmap", "crop", GOOD_PANO, "{d}/c.png", "--fov", "-5", "--size", "8x6"], SLOW),
    ("crop-fov-nan", ["envmap", "crop", GOOD_PANO, "{d}/c.png", "--fov", "nan", "--size", "8x6"], SLOW),
    ("crop-pitch-inf", ["envmap", "crop", GOOD_PANO, "{d}/c.png", "--fov", "60", "--size", "8x6", "--pitch", "inf"], ()),
    # ---- capture
    ("capture-info-missing", ["capture", "info", "{d}/missing.jpg"], SLOW),
    ("capture-info-empty", ["capture", "info", "{d}/empty.jpg"], ()),
    ("capture-info-text-jpg", ["capture", "info", "{d}/text.jpg"], ()),
    ("capture-info-trunc-jpg", ["capture", "info", "{d}/trunc.jpg"], ()),
    ("merge-missing", ["capture", "merge", "{d}/missing.jpg", "{d}/photo.jpg", "-o", "{d}/m.exr"], SLOW),
    ("merge-text-jpg", ["capture", "merge", "{d}/text.jpg", "{d}/photo.jpg", "-o", "{d}/m.exr", "--times", "1,2"], SLOW),
    ("merge-trunc-jpg", ["capture", "merge", "{d}/trunc.jpg", "{d}/photo.jpg", "-o", "{d}/m.exr", "--times", "1,2"], ()),
    ("merge-no-exif", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr"], SLOW),
    ("merge-times-count", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1"], SLOW),
    ("merge-times-text", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "a,b"], SLOW),
    ("merge-times-negative", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "-1,0"], SLOW),
    ("merge-times-nan", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "nan,1"], ()),
    ("merge-sizes-differ", ["capture", "merge", "{d}/photo.jpg", "{d}/small.jpg", "-o", "{d}/m.exr", "--times", "1,2"], ()),
    ("merge-response-missing", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1,2", "--response", "{d}/missing.json"], SLOW),
    ("merge-response-bad-json", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1,2", "--response", "{d}/bad.json"], ()),
    ("merge-response-wrong-json", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1,2", "--response", "{d}/wrong.json"], SLOW),
    ("merge-wb-bogus", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1,2", "--wb", "sunny"], ()),
    ("merge-ghost-mask-is-input", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/m.exr", "--times", "1,2", "--ghost-mask", "{d}/photo2.jpg"], ()),
    ("merge-out-parent-is-file", ["capture", "merge", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/notes.txt/m.exr", "--times", "1,2"], ()),
    ("unwarp-missing", ["capture", "unwarp", "{d}/missing.jpg", "{d}/u.exr"], SLOW),
    ("unwarp-empty", ["capture", "unwarp", "{d}/empty.jpg", "{d}/u.exr"], ()),
    ("unwarp-text-jpg", ["capture", "unwarp", "{d}/text.jpg", "{d}/u.exr"], SLOW),
    ("unwarp-trunc-exr", ["capture", "unwarp", "{d}/trunc.exr", "{d}/u.exr"], SLOW),
    ("unwarp-nan-exr", ["capture", "unwarp", "{d}/nan.exr", "{d}/u.exr", "--profile", "theta-s"], ()),
    ("unwarp-no-model", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr"], SLOW),
    ("unwarp-size-12x", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "theta-s", "--size", "12x"], ()),
    ("unwarp-size-not-2to1", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "theta-s", "--size", "100x100"], ()),
    ("unwarp-profile-bogus", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "theta-x9"], ()),
    ("unwarp-profile-bad-json", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "{d}/bad.json"], ()),
    ("unwarp-profile-wrong-json", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "{d}/wrong.json"], SLOW),
    ("unwarp-vignetting-missing", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "theta-s", "--vignetting", "{d}/missing.json"], SLOW),
    ("unwarp-vignetting-bad-json", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "theta-s", "--vignetting", "{d}/bad.json"], SLOW),
    ("unwarp-feather-nan", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.exr", "--profile", "theta-s", "--feather", "nan"], ()),
    ("unwarp-out-unknown-suffix", ["capture", "unwarp", "{d}/dual.jpg", "{d}/u.txt", "--profile", "theta-s"], ()),
    ("unwarp-out-parent-is-file", ["capture", "unwarp", "{d}/dual.jpg", "{d}/notes.txt/u.exr", "--profile", "theta-s"], SLOW),
    # ---- calibrate
    ("response-missing", ["calibrate", "response", "{d}/missing.jpg", "{d}/photo.jpg", "-o", "{d}/r.json", "--times", "1,2"], ()),
    ("response-text-jpg", ["calibrate", "response", "{d}/text.jpg", "{d}/photo.jpg", "-o", "{d}/r.json", "--times", "1,2"], SLOW),
    ("response-one-frame", ["calibrate", "response", "{d}/photo.jpg", "-o", "{d}/r.json", "--times", "1"], ()),
    ("response-no-exif", ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json"], SLOW),
    ("response-times-count", ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json", "--times", "1"], SLOW),
    ("response-times-text", ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json", "--times", "1,x"], ()),
    ("response-sizes-differ", ["calibrate", "response", "{d}/photo.jpg", "{d}/small.jpg", "-o", "{d}/r.json", "--times", "1,2"], SLOW),
    ("response-samples-too-many", ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json", "--times", "1,2", "--samples", "100000"], ()),
    ("response-out-is-input", ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/photo2.jpg", "--times", "1,2"], SLOW),
    ("response-method-bogus", ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json", "--times", "1,2", "--method", "magic"], SLOW),
    ("response-samples-zero", ["calibrate", "response", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/r.json", "--times", "1,2", "--samples", "0"], ()),
    ("colour-out-is-input", ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/pano.exr", "--corners", "1,1,30,1,30,15,1,15"], SLOW),
    ("colour-missing", ["calibrate", "colour", "{d}/missing.exr", "-o", "{d}/c.json"], SLOW),
    ("colour-text-exr", ["calibrate", "colour", "{d}/text.exr", "-o", "{d}/c.json"], SLOW),
    ("colour-nan-exr", ["calibrate", "colour", "{d}/nan.exr", "-o", "{d}/c.json"], ()),
    ("colour-no-checker", ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json"], SLOW),
    ("colour-corners-short", ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json", "--corners", "1,2,3"], ()),
    ("colour-corners-outside", ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json", "--corners", "900,900,950,900,950,950,900,950"], SLOW),
    ("colour-objective-bogus", ["calibrate", "colour", "{d}/pano.exr", "-o", "{d}/c.json", "--objective", "best"], SLOW),
    ("colour-8bit-no-response", ["calibrate", "colour", "{d}/photo.jpg", "-o", "{d}/c.json"], SLOW),
    ("camera-out-is-input", ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/photo.jpg", "--fov-deg", "60"], ()),
    ("camera-missing", ["calibrate", "camera", "{d}/missing.jpg", "-o", "{d}/k.json"], SLOW),
    ("camera-text-jpg", ["calibrate", "camera", "{d}/text.jpg", "-o", "{d}/k.json"], ()),
    ("camera-no-exif", ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/k.json"], SLOW),
    ("camera-fov-zero", ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/k.json", "--fov-deg", "0"], SLOW),
    ("camera-fov-nan", ["calibrate", "camera", "{d}/photo.jpg", "-o", "{d}/k.json", "--fov-deg", "nan"], ()),
    ("camera-pattern-12x", ["calibrate", "camera", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/k.json", "--pattern", "12x"], ()),
    ("camera-pattern-no-board", ["calibrate", "camera", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/k.json", "--pattern", "6x9"], SLOW),
    ("camera-dictionary-bogus", ["calibrate", "camera", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/k.json", "--charuco", "5x7", "--dictionary", "DICT_BOGUS"], SLOW),
    ("lens-out-is-input", ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/photo.jpg", "--pattern", "6x9"], SLOW),
    ("lens-missing", ["calibrate", "lens", "{d}/missing.jpg", "-o", "{d}/l.json", "--pattern", "6x9"], ()),
    ("lens-no-pattern", ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json"], SLOW),
    ("lens-pattern-12x", ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "12x"], SLOW),
    ("lens-no-board", ["calibrate", "lens", "{d}/photo.jpg", "{d}/photo2.jpg", "-o", "{d}/l.json", "--pattern", "6x9"], SLOW),
    ("lens-model-bogus", ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--model", "pinhole"], SLOW),
    ("lens-crop-short", ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--crop", "1,2"], ()),
    ("lens-ypr-text", ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--ypr", "a,b,c"], SLOW),
    ("lens-add-to-missing", ["calibrate", "lens", "{d}/photo.jpg", "-o", "{d}/l.json", "--pattern", "6x9", "--add-to", "{d}/missing.json"], SLOW),
    ("vignetting-out-is-input", ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/dual.jpg", "--lens-profile", "theta-s"], ()),
    ("vignetting-missing", ["calibrate", "vignetting", "{d}/missing.exr", "-o", "{d}/v.json", "--lens-profile", "theta-s"], SLOW),
    ("vignetting-text-exr", ["calibrate", "vignetting", "{d}/text.exr", "-o", "{d}/v.json", "--lens-profile", "theta-s"], ()),
    ("vignetting-profile-bogus", ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/v.json", "--lens-profile", "theta-x9"], ()),
    ("vignetting-profile-bad-json", ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/v.json", "--lens-profile", "{d}/bad.json"], SLOW),
    ("vignetting-method-bogus", ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/v.json", "--lens-profile", "theta-s", "--method", "magic"], SLOW),
    ("vignetting-degree-zero", ["calibrate", "vignetting", "{d}/dual.jpg", "-o", "{d}/v.json", "--lens-profile", "theta-s", "--degree", "0"], SLOW),
    ("vignetting-nan-exr", ["calibrate", "vignetting", "{d}/nan.exr", "-o", "{d}/v.json", "--lens-profile", "theta-s"], SLOW),
    ("overlap-out-is-input", ["calibrate", "overlap", "{d}/dual.jpg", "--base", "theta-s", "-o", "{d}/dual.jpg"], SLOW),
    ("overlap-missing", ["calibrate", "overlap", "{d}/missing.jpg", "--base", "theta-s", "-o", "{d}/o.json"], SLOW),
    ("overlap-text-jpg", ["calibrate", "overlap", "{d}/text.jpg", "--base", "theta-s", "-o", "{d}/o.json"], ()),
    ("overlap-base-bogus", ["calibrate", "overlap", "{d}/dual.jpg", "--base", "theta-x9", "-o", "{d}/o.json"], SLOW),
    ("overlap-base-bad-json", ["calibrate", "overlap", "{d}/dual.jpg", "--base", "{d}/bad.json", "-o", "{d}/o.json"], SLOW),
    ("overlap-sizes-differ", ["calibrate", "overlap", "{d}/dual.jpg", "{d}/photo.jpg", "--base", "theta-s", "-o", "{d}/o.json"], ()),
    # ---- synth (argument checks happen before any rendering)
    ("dataset-shard-text", ["synth", "dataset", "--n", "2", "--out", "{d}/ds", "--shard", "abc"], SLOW),
    ("dataset-shard-range", ["synth", "dataset", "--n", "2", "--out", "{d}/ds", "--shard", "3/2"], ()),
    ("dataset-out-is-file", ["synth", "dataset", "--n", "1", "--out", "{d}/notes.txt", "--width", "8", "--height", "6"], SLOW),
    ("dataset-reference-missing", ["synth", "dataset", "--n", "1", "--out", "{d}/ds", "--reference", "{d}/missing"], SLOW),
    ("dataset-variant-bogus", ["synth", "dataset", "--n", "1", "--out", "{d}/ds", "--variant", "bogus_rgb"], SLOW),
    ("filter-out-missing", ["synth", "filter", "--out", "{d}/missing", "--reference", "{d}/sub"], SLOW),
    ("filter-not-a-dataset", ["synth", "filter", "--out", "{d}/sub", "--reference", "{d}/sub"], SLOW),
    ("campaign-brackets-text", ["synth", "campaign", "--out", "{d}/camp", "--brackets", "fast,slow"], ()),
    ("campaign-brackets-zero", ["synth", "campaign", "--out", "{d}/camp", "--brackets", "1/0"], SLOW),
    ("campaign-variant-bogus", ["synth", "campaign", "--out", "{d}/camp", "--variant", "bogus_rgb", "--scenes", "1", "--probes", "0"], SLOW),
    ("campaign-out-is-file", ["synth", "campaign", "--out", "{d}/notes.txt", "--scenes", "1", "--probes", "0"], SLOW),
    # ---- ingest
    ("ingest-card-missing", ["ingest", "{d}/missing", "{d}/camp"], ()),
    ("ingest-card-is-file", ["ingest", "{d}/photo.jpg", "{d}/camp"], SLOW),
    ("ingest-card-empty", ["ingest", "{d}/sub", "{d}/camp"], ()),
    ("ingest-campaign-is-file", ["ingest", "{d}/card", "{d}/notes.txt"], ()),
    ("ingest-scene-gap-nan", ["ingest", "{d}/card", "{d}/camp", "--scene-gap", "nan"], ()),
    ("ingest-profile-bogus", ["ingest", "{d}/card", "{d}/camp", "--profile", "theta-x9"], ()),
    ("ingest-vignetting-missing", ["ingest", "{d}/card", "{d}/camp", "--vignetting", "{d}/missing.json"], ()),
    ("ingest-response-bad-json", ["ingest", "{d}/card", "{d}/camp", "--response", "{d}/bad.json"], SLOW),
    # ---- predict
    ("predict-missing", ["predict", "{d}/missing.jpg", "--at", "4,4", "--out", "{d}/p"], SLOW),
    ("predict-text-jpg", ["predict", "{d}/text.jpg", "--at", "4,4", "--out", "{d}/p"], SLOW),
    ("predict-trunc-jpg", ["predict", "{d}/trunc.jpg", "--at", "4,4", "--out", "{d}/p"], SLOW),
    ("predict-at-5", ["predict", "{d}/photo.jpg", "--at", "5", "--out", "{d}/p"], ()),
    ("predict-at-text", ["predict", "{d}/photo.jpg", "--at", "a,b", "--out", "{d}/p"], SLOW),
    ("predict-at-outside", ["predict", "{d}/photo.jpg", "--at", "1000,1000", "--out", "{d}/p"], SLOW),
    ("predict-at-nan", ["predict", "{d}/photo.jpg", "--at", "nan,3", "--out", "{d}/p"], SLOW),
    ("predict-intrinsics-short", ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--intrinsics", "1,2"], SLOW),
    ("predict-fov-zero", ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--fov", "0"], SLOW),
    ("predict-pitch-nan", ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--pitch", "nan"], ()),
    ("predict-checkpoint-missing", ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--checkpoint", "{d}/missing.pt"], SLOW),
    ("predict-checkpoint-text", ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/p", "--checkpoint", "{d}/notes.txt"], SLOW),
    ("predict-out-is-file", ["predict", "{d}/photo.jpg", "--at", "4,4", "--out", "{d}/notes.txt"], SLOW),
    # ---- demo
    ("demo-card-missing", ["demo", "--out", "{d}/demo", "--card", "{d}/missing"], ()),
    ("demo-card-is-file", ["demo", "--out", "{d}/demo", "--card", "{d}/notes.txt"], SLOW),
    ("demo-out-is-file", ["demo", "--out", "{d}/notes.txt", "--card", "{d}/sub"], ()),
    # ---- eval / finetune
    ("eval-no-data", ["eval", "-o", "{d}/ev"], ()),
    ("eval-testset-missing", ["eval", "--testset", "{d}/missing", "-o", "{d}/ev"], SLOW),
    ("eval-testset-not-a-testset", ["eval", "--testset", "{d}/sub", "-o", "{d}/ev"], ()),
    ("eval-baseline-no-name", ["eval", "--testset", "{d}/sub", "--baseline", "{d}/notes.txt", "-o", "{d}/ev"], SLOW),
    ("eval-model-missing", ["eval", "--testset", "{d}/sub", "--model", "{d}/missing.pt", "-o", "{d}/ev"], SLOW),
    ("finetune-testset-not-a-testset", ["finetune", "--testset", "{d}/sub", "-o", "{d}/ft"], ()),
    ("finetune-trainable-bad", ["finetune", "--testset", "{d}/sub", "--trainable", "head", "-o", "{d}/ft"], SLOW),
    ("finetune-folds-1", ["finetune", "--testset", "{d}/sub", "--folds", "1", "-o", "{d}/ft"], SLOW),
]


def _jpeg(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def make_bad_inputs(d: Path) -> None:
    """Write the tiny bad (and a few good) inputs the cases refer to."""
    rng = np.random.default_rng(0)
    d.mkdir(parents=True, exist_ok=True)
    (d / "sub").mkdir()
    (d / "notes.txt").write_text("not an image\n")
    for name in ("empty.jpg", "empty.exr"):
        (d / name).write_bytes(b"")
    for name in ("text.jpg", "text.exr"):
        (d / name).write_text("hello, I am a text file\n")
    (d / "bad.json").write_text('{"lenses": [')
    (d / "wrong.json").write_text(json.dumps({"hello": 1}))
    pano = (rng.random((16, 32, 3)) * 2).astype(np.float32)
    write_exr(d / "pano.exr", pano)
    write_exr(d / "notpano.exr", pano[:, :24])
    nan = pano.copy()
    nan[3, 5] = np.nan
    write_exr(d / "nan.exr", nan)
    inf = pano.copy()
    inf[4, 6, 1] = np.inf
    write_exr(d / "inf.exr", inf, half=False)
    data = (d / "pano.exr").read_bytes()
    (d / "trunc.exr").write_bytes(data[: len(data) // 2])
    photo = (rng.random((48, 64, 3)) * 255).astype(np.uint8)
    (d / "photo.jpg").write_bytes(_jpeg(photo))
    (d / "photo2.jpg").write_bytes(_jpeg(photo // 2))
    (d / "small.jpg").write_bytes(_jpeg(photo[:24, :32]))
    (d / "dual.jpg").write_bytes(_jpeg((rng.random((64, 128, 3)) * 255).astype(np.uint8)))
    jpg = (d / "photo.jpg").read_bytes()
    (d / "trunc.jpg").write_bytes(jpg[: len(jpg) // 3])
    card = d / "card" / "DCIM"
    card.mkdir(parents=True)
    (card / "R0010001.JPG").write_bytes(jpg[: len(jpg) // 3])


def snapshot(d: Path) -> dict[str, tuple[int, int]]:
    """Every path under ``d`` (directories too) with its size and mtime."""
    out = {}
    for p in d.rglob("*"):
        st = p.lstat()
        out[str(p.relative_to(d))] = (st.st_size if p.is_file() else -1, st.st_mtime_ns)
    return out


def run_cli(argv: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "200", "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        [sys.executable, "-m", "solidkit.cli", *argv], capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout
    )


@pytest.fixture(scope="module")
def bad_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bad") / "in"
    make_bad_inputs(d)
    return d


@pytest.mark.parametrize("argv", [pytest.param(a, id=i, marks=m) for i, a, m in CASES])
def test_bad_input_is_one_clear_line(bad_dir: Path, argv: list[str]) -> None:
    args = [a.replace("{d}", str(bad_dir)) for a in argv]
    before = snapshot(bad_dir)
    res = run_cli(args, cwd=bad_dir)
    output = res.stdout + res.stderr
    assert res.returncode != 0, output
    assert "Traceback" not in output, output
    err = [line for line in res.stderr.splitlines() if line.strip()]
    assert err and err[-1].startswith("error: "), f"no one-line error: {res.stderr!r}"
    assert "Warning" not in res.stderr, res.stderr
    after = snapshot(bad_dir)
    assert after == before, f"files changed: {sorted(set(after.items()) ^ set(before.items()))}"


def test_jpeg_truncated(tmp_path: Path) -> None:
    from solidkit.fsutil import jpeg_truncated

    jpg = _jpeg(np.zeros((16, 16, 3), np.uint8))
    cases = {
        "ok.jpg": jpg,
        "padded.jpg": jpg + b"\0" * 100,
        "trailer.jpg": jpg + b"motion-photo video" * 500,  # data after the end marker is legal
        "cut.jpg": jpg[:-10],
        "text.jpg": b"hello",
        "empty.jpg": b"",
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
    assert {n: jpeg_truncated(tmp_path / n) for n in cases} == {
        "ok.jpg": False, "padded.jpg": False, "trailer.jpg": False, "cut.jpg": True, "text.jpg": False,
        "empty.jpg": False,
    }


def test_output_naming_an_input_is_refused_except_in_place_updates(tmp_path: Path) -> None:
    from solidkit.cli import refuse_overwriting_inputs
    from solidkit.errors import InputError

    src, other = tmp_path / "a.jpg", tmp_path / "b.json"
    src.write_bytes(b"x")
    other.write_text("{}")
    calls = []
    cmd = refuse_overwriting_inputs(lambda **kw: calls.append(kw))
    with pytest.raises(InputError, match="refusing to overwrite"):
        cmd(frames=[src], out=src)
    with pytest.raises(InputError, match="refusing to overwrite"):
        cmd(image=src, out=tmp_path / "new.json", ghost_mask=src)
    cmd(frames=[src], out=other)  # an existing non-input output is simply replaced
    cmd(views=[src], out=other, add_to=other)  # calibrate lens --add-to P -o P updates P
    assert len(calls) == 2 and src.read_bytes() == b"x"
