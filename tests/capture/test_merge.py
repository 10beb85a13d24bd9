"""HDR bracket merging against ground truth: a known HDR exposed through a response curve."""

from __future__ import annotations

import json
from datetime import datetime, timedelta
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from solidkit.camera.raw import RawImage
from solidkit.capture.bracket_groups import ShotInfo, format_exposure, group_brackets, sequence_from_name
from solidkit.capture.bracket_merge import merge_files
from solidkit.capture.frame_merge import (
    dynamic_range_stops,
    frame_from_ldr,
    frame_from_raw,
    load_frame,
    load_response,
    merge_frames,
    srgb_response,
    validate_response,
)
from solidkit.envmap.io import read_exr
from solidkit.errors import InputError

ASSETS = Path(__file__).resolve().parents[2] / "solidkit" / "assets" / "hdr_panoramas"
TIMES = [1 / 64, 1 / 8, 1.0, 8.0]
CODES = np.arange(256) / 255.0


def camera_curve(x: np.ndarray) -> np.ndarray:
    """A non-sRGB forward response (gamma 1/2.4 with a soft shoulder), monotone on [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return (x ** (1 / 2.4)) * (1.15 - 0.15 * x)


def inverse_table(curve=camera_curve) -> np.ndarray:
    """The exact inverse response (256, 3) of ``curve`` by dense inversion."""
    xs = np.linspace(0, 1, 200001)
    return np.repeat(np.interp(CODES, curve(xs), xs)[:, None], 3, axis=1)


@pytest.fixture(scope="module")
def scene() -> np.ndarray:
    """The city panorama (real HDR, sun ~35k) at 256x128, scaled so the median is ~0.06."""
    hdr, _ = read_exr(ASSETS / "city.exr")
    hdr = cv2.resize(hdr, (256, 128), interpolation=cv2.INTER_AREA).astype(np.float64)
    return hdr * (0.06 / np.median(hdr))


def expose(E: np.ndarray, t: float, rng, curve=camera_curve, shot=0.01, read=0.002) -> np.ndarray:
    """Expose radiance E for time t: multiplicative + read noise, clipping, response, 8-bit."""
    x = E * t
    x = x * (1 + shot * rng.standard_normal(x.shape)) + read * rng.standard_normal(x.shape)
    return np.round(255 * curve(x)).astype(np.uint8)


def well_exposed(frames) -> np.ndarray:
    good = np.zeros(frames[0].code.shape[:2], bool)
    for f in frames:
        good |= ((f.code > 0.1) & (f.code < 0.9)).all(-1)
    return good


def test_merge_recovers_synthetic_hdr(scene):
    rng = np.random.default_rng(1)
    R = inverse_table()
    frames = [frame_from_ldr(expose(scene, t, rng), t, R, name=f"t{t}") for t in TIMES]
    res = merge_frames(frames)
    good = well_exposed(frames) & ~res.saturated
    assert good.mean() > 0.95
    rel = np.abs(res.hdr - scene) / scene
    err = float(np.median(rel[good]))
    assert err < 0.02, err
    # the merged dynamic range matches the scene's (sun excluded: it clips in every frame)
    dr, dr_true = dynamic_range_stops(res.hdr, res.saturated), dynamic_range_stops(scene, res.saturated)
    assert abs(dr - dr_true) < 0.25, (dr, dr_true)
    print(
        f"synthetic merge: median relative error {100 * err:.2f} % on {100 * good.mean():.1f} % of pixels; "
        f"dynamic range {dr:.2f} stops (truth {dr_true:.2f})"
    )
    assert res.ghost_fraction < 0.002  # a static scene has (almost) no ghosts


def test_wrong_response_fails_the_bound(scene):
    """The 2 % bound is not vacuous: decoding with sRGB instead of the camera's curve breaks it."""
    rng = np.random.default_rng(1)
    frames = [frame_from_ldr(expose(scene, t, rng), t, srgb_response()) for t in TIMES]
    res = merge_frames(frames)
    good = well_exposed(frames) & ~res.saturated
    ratio = res.hdr[good] / scene[good]
    ratio /= np.median(ratio)  # even allowing a free global scale
    assert np.median(np.abs(ratio - 1)) > 0.02


def test_saturated_everywhere_takes_shortest_and_is_flagged():
    E = np.full((32, 32, 3), 0.5)
    E[8:16, 8:16] = 5000.0  # a "sun": clipped even at the shortest exposure
    R = inverse_table()
    rng = np.random.default_rng(0)
    frames = [frame_from_ldr(expose(E, t, rng, shot=0, read=0), t, R) for t in (1 / 64, 1 / 8, 1.0)]
    res = merge_frames(frames)
    sun = np.zeros((32, 32), bool)
    sun[8:16, 8:16] = True
    np.testing.assert_array_equal(res.saturated, sun)
    np.testing.assert_allclose(res.hdr[sun], R[255, 0] * 64, rtol=1e-5)  # shortest frame's value
    np.testing.assert_allclose(res.hdr[~sun], 0.5, rtol=0.02)


def test_black_everywhere_takes_longest_and_is_flagged():
    E = np.full((16, 16, 3), 0.5)
    E[:4] = 1e-6
    R = inverse_table()
    frames = [frame_from_ldr(expose(E, t, np.random.default_rng(0), shot=0, read=0), t, R) for t in (1 / 8, 1.0)]
    res = merge_frames(frames)
    assert res.underexposed[:4].all() and not res.underexposed[4:].any()


def test_ghost_detection_flags_a_moved_square(scene):
    rng = np.random.default_rng(2)
    R = inverse_table()
    a = (slice(40, 60), slice(60, 80))
    b = (slice(40, 60), slice(150, 170))
    frames = []
    for i, t in enumerate(TIMES):
        Ei = scene.copy()
        Ei[a if i == 1 else b] = (0.3, 0.05, 0.02)  # a red object that moved between shots
        frames.append(frame_from_ldr(expose(Ei, t, rng), t, R))
    truth = np.zeros(scene.shape[:2], bool)
    truth[a] = truth[b] = True
    res = merge_frames(frames)
    recall = (res.ghost & truth).sum() / truth.sum()
    false_pos = (res.ghost & ~truth).sum() / (~truth).sum()
    assert recall > 0.9, recall
    assert false_pos < 0.005, false_pos
    assert abs(res.ghost_fraction - res.ghost.mean()) < 1e-12
    # deghosting keeps the reference frame's content inside the ghost
    fixed = merge_frames(frames, deghost=True)
    ref_scene = scene.copy()
    ref_scene[a if fixed.reference == 1 else b] = (0.3, 0.05, 0.02)
    inside = truth & fixed.ghost
    err_plain = np.median(np.abs(res.hdr[inside] - ref_scene[inside]) / ref_scene[inside])
    err_fixed = np.median(np.abs(fixed.hdr[inside] - ref_scene[inside]) / ref_scene[inside])
    assert err_fixed < 0.05 < err_plain


def test_raw_frames_merge_linearly():
    rng = np.random.default_rng(3)
    E = np.exp(rng.uniform(np.log(1e-3), np.log(50.0), (24, 24, 3)))
    frames = []
    for t in (1 / 16, 1 / 2, 4.0):
        lin = np.clip(E * t * (1 + 0.005 * rng.standard_normal(E.shape)), 0, 1.0)
        sat = (E * t >= 1.0).any(-1)
        frames.append(frame_from_raw(RawImage(lin.astype(np.float32), sat, [0.0], 1.0, [1, 1, 1], "camera"), t))
    res = merge_frames(frames)
    ok = ~res.saturated & (E.min(-1) * 4.0 > 0.01)
    assert np.median(np.abs(res.hdr[ok] - E[ok]) / E[ok]) < 0.01


def test_duplicate_exposures_rejected():
    img = np.full((8, 8, 3), 100, np.uint8)
    with pytest.raises(InputError, match="same exposure"):
        merge_frames([frame_from_ldr(img, 0.5), frame_from_ldr(img, 0.5)])


def test_response_validation_and_profile_file(tmp_path):
    with pytest.raises(InputError, match="non-decreasing"):
        validate_response(np.linspace(1, 0, 256))
    with pytest.raises(InputError, match="shape"):
        validate_response(np.ones((255, 3)))
    assert validate_response(np.linspace(0, 1, 256)).shape == (256, 3)
    # a saved response profile (solidkit.calibration) is read through its own loader
    from solidkit.calibration.profile import make_provenance
    from solidkit.calibration.response import ResponseProfile

    curve = inverse_table()
    prof = ResponseProfile(provenance=make_provenance(tool="test"), method="synthetic", curve=curve.tolist())
    prof.save(tmp_path / "resp.json")
    np.testing.assert_allclose(load_response(tmp_path / "resp.json"), curve, rtol=1e-6)
    np.save(tmp_path / "r.npy", curve)
    np.testing.assert_allclose(load_response(tmp_path / "r.npy"), curve)
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(InputError):
        load_response(tmp_path / "bad.json")


def test_bracket_grouping():
    t0 = datetime(2024, 6, 1, 12, 0, 0)
    shots = [
        # bracket 1 (frobisher-like: 1/8, 1, 8 s one second apart)
        ShotInfo("a", t0, 1, 0.125, "cam", (64, 32)),
        ShotInfo("b", t0 + timedelta(seconds=1), 2, 1.0, "cam", (64, 32)),
        ShotInfo("c", t0 + timedelta(seconds=3), 3, 8.0, "cam", (64, 32)),
        # bracket 2 right after: exposure repeats -> new bracket
        ShotInfo("d", t0 + timedelta(seconds=12), 4, 0.125, "cam", (64, 32)),
        ShotInfo("e", t0 + timedelta(seconds=13), 5, 1.0, "cam", (64, 32)),
        # a single shot two minutes later
        ShotInfo("f", t0 + timedelta(minutes=2), 6, 1 / 25000, "cam", (64, 32)),
        # another camera at the same time is never mixed in
        ShotInfo("g", t0 + timedelta(seconds=1), 1, 0.5, "other", (64, 32)),
    ]
    groups = [[s.key for s in g] for g in group_brackets(shots[::-1])]
    assert groups == [["a", "b", "c"], ["g"], ["d", "e"], ["f"]]
    # without timestamps: consecutive sequence numbers
    noclock = [ShotInfo(k, None, n, e) for k, n, e in [("x", 10, 0.1), ("y", 11, 1.0), ("z", 14, 0.1)]]
    assert [[s.key for s in g] for g in group_brackets(noclock)] == [["x", "y"], ["z"]]
    # an ISO bracket at a fixed shutter is one bracket; a repeated (time, ISO) is not
    iso = [
        ShotInfo(k, t0 + timedelta(seconds=i), None, 0.01, gain=g)
        for i, (k, g) in enumerate([("i1", 1.0), ("i2", 4.0), ("i3", 16.0), ("i4", 16.0)])
    ]
    assert [[s.key for s in g] for g in group_brackets(iso)] == [["i1", "i2", "i3"], ["i4"]]
    assert sequence_from_name("DCIM/100RICOH/R0010123.JPG") == 10123
    assert format_exposure(1 / 25000) == "1/25000 s" and format_exposure(8) == "8 s"


def _write_bracket(tmp_path: Path, scene: np.ndarray) -> list[Path]:
    rng = np.random.default_rng(4)
    paths = []
    for i, t in enumerate(TIMES[:3]):
        p = tmp_path / f"R00100{i + 1:02d}.png"
        cv2.imwrite(
            str(p),
            cv2.cvtColor(expose(scene, t, rng, curve=lambda x: np.clip(x, 0, 1) ** (1 / 2.2)), cv2.COLOR_RGB2BGR),
        )
        paths.append(p)
    return paths


def test_merge_files_writes_exr_with_provenance(tmp_path, scene):
    paths = _write_bracket(tmp_path, scene)
    out = tmp_path / "out.exr"
    gamma = np.repeat((CODES**2.2)[:, None], 3, axis=1)
    summaries = merge_files(paths, out, times=TIMES[:3], response=gamma, ghost_mask_path=tmp_path / "ghost.png")
    hdr, meta = read_exr(out)
    prov = meta["provenance"]
    assert [i["effective_exposure"] for i in prov["inputs"]] == TIMES[:3]
    assert all(len(i["sha256"]) == 64 for i in prov["inputs"])
    assert prov["solidkit_version"] and prov["stats"]["dynamic_range_stops"] == summaries[0]["dynamic_range_stops"]
    assert (tmp_path / "ghost.png").is_file()
    mid = np.clip(scene * TIMES[1], 0, 1) ** (1 / 2.2)
    good = ((mid > 0.1) & (mid < 0.9)).all(-1)
    rel = np.abs(hdr - scene) / scene
    assert np.median(rel[good]) < 0.03
    assert not list(tmp_path.glob(".out.exr*"))  # no temporary left behind


def test_merge_cli_errors(tmp_path, scene):
    from solidkit.cli import app

    paths = _write_bracket(tmp_path, scene)
    runner = CliRunner()
    r = runner.invoke(
        app, ["capture", "merge", *map(str, paths[:2]), "-o", str(tmp_path / "x.exr"), "--times", "1/8,0.125"]
    )
    assert r.exit_code != 0 and "same exposure" in str(r.exception)
    r = runner.invoke(app, ["capture", "merge", *map(str, paths[:2]), "-o", str(tmp_path / "x.exr")])
    assert "no exposure time" in str(r.exception)  # PNGs carry no EXIF
    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        load_frame(tmp_path / "empty.jpg", 1.0)
    trunc = tmp_path / "trunc.jpg"
    ok, buf = cv2.imencode(".jpg", np.full((64, 64, 3), 128, np.uint8))
    trunc.write_bytes(buf.tobytes()[: len(buf) // 2])
    with pytest.raises(InputError, match="cannot decode"):
        load_frame(trunc, 1.0)
    fake = tmp_path / "raw.jpg"
    fake.write_bytes(b"II*\x00" + bytes(100))
    with pytest.raises(InputError, match="rename it to .dng"):
        load_frame(fake, 1.0)


@pytest.mark.real
def test_real_frobisher_brackets_merge(real_data, tmp_path):
    from solidkit.cli import app

    frames = sorted((real_data / "brackets_frobisher").glob("IMG_26*.jpg"))
    out = tmp_path / "frobisher.exr"
    r = CliRunner().invoke(app, ["capture", "merge", *map(str, frames), "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    stats = json.loads(r.output)[0]
    hdr, meta = read_exr(out)
    assert hdr.shape == (426, 640, 3) and np.isfinite(hdr).all() and hdr.min() >= 0
    assert [i["exposure_time"] for i in meta["provenance"]["inputs"]] == [0.125, 1.0, 8.0]  # from EXIF
    # 3 frames, 6 stops apart: well beyond one JPEG's ~8 stops
    assert stats["dynamic_range_stops"] > 10
    print(
        f"frobisher: dynamic range {stats['dynamic_range_stops']:.2f} stops, ghosts "
        f"{100 * stats['ghost_fraction']:.2f} %, saturated in all frames "
        f"{100 * stats['saturated_in_all_frames_fraction']:.2f} %"
    )


@pytest.mark.real
def test_real_frobisher_with_calibrated_response(real_data, tmp_path):
    """Without --response the curve is estimated from the bracket itself (recorded as such),
    which removes the sRGB-mismatch 'ghosts' (<= 2 % false positives on this static bracket) like a
    calibrated profile does; sRGB is only used when asked or when it must be assumed (then warned)."""
    from solidkit.calibration.response import calibrate_response_files
    from solidkit.capture.frame_merge import srgb_response

    frames = sorted((real_data / "brackets_frobisher").glob("IMG_26*.jpg"))
    calibrate_response_files(frames).save(tmp_path / "canon.json")
    auto = merge_files(frames, tmp_path / "a.exr")[0]
    srgb = merge_files(frames, tmp_path / "s.exr", response=srgb_response())[0]
    cal = merge_files(frames, tmp_path / "b.exr", response_path=tmp_path / "canon.json")[0]
    _, meta = read_exr(tmp_path / "b.exr")
    assert meta["provenance"]["response"]["kind"] == "file" and len(meta["provenance"]["response"]["sha256"]) == 64
    _, meta = read_exr(tmp_path / "a.exr")
    assert meta["provenance"]["response"]["kind"] == "estimated" and meta["provenance"]["response"]["frames"] == 3
    assert auto["response"]["kind"] == "estimated" and not auto["warnings"]
    assert all(abs(dx) < 0.5 and abs(dy) < 0.5 for dx, dy in auto["registration"]["shifts_px"])  # a tripod bracket
    print(
        f"frobisher ghost fraction: sRGB response {100 * srgb['ghost_fraction']:.2f} %, estimated from the frames "
        f"{100 * auto['ghost_fraction']:.2f} %, calibrated {100 * cal['ghost_fraction']:.2f} %"
    )
    assert auto["ghost_fraction"] <= 0.02 and cal["ghost_fraction"] < 0.01 < srgb["ghost_fraction"]
    # two frames: nothing to estimate from -> sRGB assumed, and said so
    two = merge_files(frames[:2], tmp_path / "two.exr")[0]
    assert two["response"]["kind"] == "srgb_assumed" and any(w.startswith("srgb_assumed") for w in two["warnings"])


def test_frames_read_by_content_and_registered(tmp_path, scene):
    """A JPEG named .png is read as the JPEG it is (and said so); a frame shifted by
    (-0.7, +0.8) px is registered (shift recorded and undone) instead of merged smeared."""
    paths = _write_bracket(tmp_path, scene)
    jpeg_named_png = tmp_path / "R0010009.png"
    img = cv2.imread(str(paths[1]))
    cv2.imwrite(str(tmp_path / "tmp.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 98])
    (tmp_path / "tmp.jpg").rename(jpeg_named_png)
    gamma = np.repeat((CODES**2.2)[:, None], 3, axis=1)
    s = merge_files([paths[0], jpeg_named_png, paths[2]], tmp_path / "a.exr", times=TIMES[:3], response=gamma)[0]
    assert any(w.startswith("content_not_suffix: R0010009.png is a JPEG") for w in s["warnings"])
    # shift the longest frame's content by (-0.7, +0.8) px
    long = cv2.imread(str(paths[2]))
    h, w = long.shape[:2]
    shifted = cv2.warpAffine(
        long, np.float32([[1, 0, -0.7], [0, 1, 0.8]]), (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE
    )
    cv2.imwrite(str(tmp_path / "shifted.png"), shifted)
    s = merge_files(
        [paths[0], paths[1], tmp_path / "shifted.png"], tmp_path / "b.exr", times=TIMES[:3], response=gamma
    )[0]
    dx, dy = s["registration"]["shifts_px"][2]
    assert s["registration"]["applied"][2] and abs(dx + 0.7) < 0.25 and abs(dy - 0.8) < 0.25, s["registration"]
    unaligned = merge_files(
        [paths[0], paths[1], tmp_path / "shifted.png"], tmp_path / "c.exr", times=TIMES[:3], response=gamma, align=False
    )[0]
    assert s["ghost_fraction"] <= unaligned["ghost_fraction"]


_THREADED_MERGE = """
import hashlib, sys
from solidkit.capture.bracket_merge import merge_bracket
from solidkit.threads import apply_threads
apply_threads(int(sys.argv[1]))
paths, times = sys.argv[2::2], [float(t) for t in sys.argv[3::2]]
result, _ = merge_bracket(paths, times, align=False)
print(hashlib.sha256(result.hdr.tobytes()).hexdigest())
"""


def test_a_merged_bracket_is_the_same_whatever_the_thread_count(tmp_path):
    """The response curve is a least-squares solve that the BLAS libraries split by thread: a bracket of
    the shipped card (a quarter size, as PNG) merged with 1 and with 2 threads gives the same bits."""
    import subprocess
    import sys

    from solidkit.camera.metadata import read_metadata

    frames = sorted((ASSETS.parent / "campaign_mini" / "card" / "scene02" / "p01").glob("R*.JPG"))
    assert len(frames) == 3
    args = []
    for f in frames:
        small = tmp_path / f"{f.stem}.png"
        cv2.imwrite(str(small), cv2.resize(cv2.imread(str(f)), None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA))
        args += [str(small), repr(read_metadata(f).exposure_time)]
    digests = {
        subprocess.run(
            [sys.executable, "-c", _THREADED_MERGE, str(n), *args],
            check=True,
            capture_output=True,
            text=True,
            timeout=300,
        ).stdout.strip()
        for n in (1, 2)
    }
    assert len(digests) == 1, digests


def test_the_merge_in_threads_is_the_merge_in_one(monkeypatch):
    """The merge and the ghost detector spread their row blocks over threads: a bracket of the shipped card
    (8 blocks) gives the same radiance, weights, ghost mask, noise levels and reference as block by block."""
    import solidkit.capture.frame_merge as fm
    from solidkit.camera.metadata import read_metadata

    paths = sorted((ASSETS.parent / "campaign_mini" / "card" / "scene01" / "p01").glob("R*.JPG"))
    frames = [fm.load_frame(p, read_metadata(p).exposure_time) for p in paths]
    threaded = fm.merge_frames(frames)
    calls = []

    def one_by_one(fn, items):
        calls.append(len(items))
        return [fn(item) for item in items]

    monkeypatch.setattr(fm, "_map_blocks", one_by_one)
    single = fm.merge_frames(frames)
    assert max(calls) >= 8
    for name in ("hdr", "weight_sum", "saturated", "underexposed", "ghost"):
        assert np.array_equal(getattr(threaded, name), getattr(single, name)), name
    assert threaded.noise_sigma == single.noise_sigma and threaded.reference == single.reference


def test_raw_bracket_shift_is_applied(monkeypatch):
    """A raw frame that registers with a shift is moved (RawImage is frozen: a new one replaces it)."""
    import solidkit.capture.bracket_merge as bm

    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.random((128, 192, 3)).astype(np.float32), (0, 0), 3) * 0.5
    frames = {}
    for k, (e, dx) in enumerate([(0.5, 0), (1.0, 0), (2.0, 3)]):
        lin = np.clip(np.roll(base * e, dx, axis=1), 0, 1).astype(np.float32)
        frames[f"f{k}.dng"] = RawImage(lin, np.zeros(lin.shape[:2], bool), [0.0], 1.0, [1.0] * 3, "srgb")
    monkeypatch.setattr(bm, "is_raw_file", lambda p: True)
    monkeypatch.setattr(bm, "read_raw", lambda p, wb=None: frames[Path(p).name])
    _, prov = bm.merge_bracket(list(frames), [0.5, 1.0, 2.0], align=True)
    reg = prov["registration"]
    assert reg["applied"] == [False, False, True]
    assert reg["shifts_px"][2][0] == pytest.approx(3.0, abs=0.1)
