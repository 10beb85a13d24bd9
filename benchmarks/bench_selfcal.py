"""Any dual-fisheye camera from one frame, and profiles that do not fit: measured.

1. **Recovery on rendered frames** with a known truth: the real CC0 HDR panoramas city, courtyard
   and sunrise (``../shared/data/real/hdr_panoramas``) seen through two lenses of a given family
   (equidistant, equisolid, Ricoh's Theta table), field of view, image circles (960x480 side by side,
   480x960 stacked), layout roll (0, ±90°) and back-lens aim, rendered with solidkit's forward model
   (:func:`solidkit.capture.unwarp.render_fisheye`) and stored as 8-bit sRGB. ``solidkit calibrate
   fisheye`` (:func:`solidkit.calibration.lensfit.fit_dual_fisheye`, refinement on) must recover the
   family, the field of view, the centres, the layout; the seam error before/after refinement.
2. **Real frames**: the Theta S live frame (``theta_s_dualfisheye``): ``calibrate fisheye`` from
   scratch; ``calibrate overlap --base theta-s-video`` (bounded, refused if worse); the frame with
   its circles turned back by 90°.
3. **The refinement from another camera's profile** (the Gear 360 case): a rendered Gear-like frame
   (equidistant 195°, circles ~10 % off theta-v's) refined from ``theta-v`` by calibration/overlap.py before the
   fit of lens families (the git revision ``--old REV``, e.g. ``e573428~1``) and now.
4. **The warning**: seam errors of correct and wrong profiles (another camera, a back lens 1-8°
   off, centres 3 % off, the wrong field of view) on rendered Theta V frames, the virtual campaign's
   Theta V JPEGs (solidkit/assets/campaign_mini) and the real Theta S frame; and the layout check
   (which way is up) on upright and ±90°-turned panoramas.

Writes benchmarks/results/selfcal.json and .md. Run:
``nice -n 10 .venv/bin/python benchmarks/bench_selfcal.py [--old e573428~1]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real"
OUT = Path(__file__).resolve().parent / "results"
sys.path.insert(0, str(REPO))

from solidkit.calibration.circles import Circle  # noqa: E402
from solidkit.calibration.fitcheck import SEAM_ERROR_WARN, check_profile_fit, check_upright  # noqa: E402
from solidkit.calibration.lensfit import fit_dual_fisheye, fit_file, start_profile  # noqa: E402
from solidkit.calibration.overlap import refine_files  # noqa: E402
from solidkit.calibration.seam import prepare_seam_image, seam_error  # noqa: E402
from solidkit.calibration.upright import CONFIDENT_MARGIN, upright_of_panorama  # noqa: E402
from solidkit.camera.dualfisheye import read_input, read_linear  # noqa: E402
from solidkit.camera.lens import load_profile  # noqa: E402
from solidkit.capture.unwarp import render_fisheye, unwarp_srgb8  # noqa: E402
from solidkit.envmap.coords import rotation_z  # noqa: E402
from solidkit.envmap.io import read_exr, srgb_decode, srgb_encode, tonemap, write_ldr  # noqa: E402
from solidkit.envmap.resample import rotate  # noqa: E402

SIZE = (960, 480)
CIRCLES = [Circle(237.3, 241.2, 226.0, 1.0), Circle(719.6, 238.4, 224.0, 1.0)]
STACKED = [Circle(241.0, 237.0, 226.0, 1.0), Circle(238.5, 721.0, 224.0, 1.0)]
GEAR = [Circle(256.0, 228.0, 207.0, 1.0), Circle(699.0, 256.0, 208.5, 1.0)]


def panorama(name: str) -> np.ndarray:
    pano, _ = read_exr(REAL / "hdr_panoramas" / f"{name}.exr")
    return np.clip(tonemap(pano), 0, 1).astype(np.float32)


def truth_profile(family, half_fov, roll=0.0, circles=CIRCLES, size=SIZE, offset=(0.0, 0.0)):
    p = start_profile(circles, size, family, half_fov, 0.0, roll, back_offset_deg=offset)
    return p.model_copy(update={"lenses": [l.model_copy(update={"max_angle_deg": half_fov}) for l in p.lenses]})


def camera_frame(pano, prof, size=SIZE) -> np.ndarray:
    fish = render_fisheye(pano, prof, size)
    return np.asarray(srgb_decode(np.round(np.clip(np.asarray(srgb_encode(fish)), 0, 1) * 255) / 255), np.float32)


def to_uint8(img) -> np.ndarray:
    return (np.clip(np.asarray(srgb_encode(img)), 0, 1) * 255 + 0.5).astype(np.uint8)


def rotation_deg(Ra, Rb) -> float:
    return math.degrees(math.acos(min(1.0, max(-1.0, (np.trace(Ra.T @ Rb) - 1) / 2))))


def recovery(panos) -> list[dict]:
    cases = [
        ("city", "equidistant", 95.0, 0.0, "side", (0.0, 0.0)),
        ("city", "equisolid", 100.0, 90.0, "side", (0.0, 0.0)),
        ("city", "theta", 100.0, -90.0, "side", (0.0, 0.0)),
        ("courtyard", "equidistant", 100.0, -90.0, "side", (1.0, -0.8)),
        ("courtyard", "equisolid", 96.0, 0.0, "stacked", (0.0, 0.0)),
        ("sunrise", "theta", 100.0, 90.0, "side", (-0.8, 0.6)),
        ("sunrise", "equidistant", 97.5, 0.0, "stacked", (0.0, 0.0)),
    ]
    rows = []
    for scene, fam, hf, roll, arr, off in cases:
        circles, size = (CIRCLES, SIZE) if arr == "side" else (STACKED, SIZE[::-1])
        truth = truth_profile(fam, hf, roll, circles, size, off)
        t0 = time.perf_counter()
        fit = fit_dual_fisheye(camera_frame(panos[scene], truth, size), 0.98)
        dt = time.perf_counter() - t0
        lay = {0.0: "upright", 90.0: "rotated +90°", -90.0: "rotated -90°"}[roll]
        row = {
            "scene": scene,
            "truth": {
                "family": fam,
                "fov_deg": 2 * hf,
                "roll_deg": roll,
                "arrangement": arr,
                "back_aim_offset_deg": list(off),
            },
            "family": fit.family,
            "fov_deg": round(2 * fit.half_fov_deg, 2),
            "layout": fit.layout,
            "family_ok": fit.family == fam,
            "layout_ok": fit.layout.endswith(lay),
            "fov_error_deg": round(2 * fit.half_fov_deg - 2 * hf, 2),
            "center_error_px": [
                round(math.dist(a.center, b.center), 3) for a, b in zip(fit.profile.lenses, truth.lenses)
            ],
            "back_rotation_error_deg": round(
                rotation_deg(
                    fit.profile.lenses[0].rotation.T @ fit.profile.lenses[1].rotation,
                    truth.lenses[0].rotation.T @ truth.lenses[1].rotation,
                ),
                3,
            ),
            "upright": fit.upright.to_json(),
            "seam_error_start": round(fit.seam_start["seam_error"], 4),
            "seam_error_refined": round(fit.scans["refined_seam"]["seam_error"], 4),
            "seam_error_kept": round(fit.seam_final["seam_error"], 4),
            "refused": fit.refusal is not None,
            "families": {
                k: [round(2 * v["half_fov_deg"], 2), round(v["seam_error"], 4)]
                for k, v in fit.scans["families"].items()
            },
            "seconds": round(dt, 1),
        }
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def old_overlap(rev: str):
    src = subprocess.run(
        ["git", "show", f"{rev}:solidkit/calibration/overlap.py"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout
    path = Path(tempfile.mkdtemp()) / "overlap_old.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("overlap_old", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["overlap_old"] = mod
    spec.loader.exec_module(mod)
    return mod


def seam_of(path: Path, prof) -> float:
    img, sat = read_linear(path)
    r = float(np.mean([l.max_radius() for l in prof.scaled(img.shape[1], img.shape[0]).lenses]))
    return seam_error(prepare_seam_image(img, r, sat), prof)["seam_error"]


def gear_case(panos, tmp: Path, old_rev: str | None) -> dict:
    src = tmp / "gear.png"
    write_ldr(src, camera_frame(panos["city"], truth_profile("equidistant", 97.5, circles=GEAR)), encode_srgb=True)
    out = {"frame": "city through equidistant 195° lenses, circles (256, 228) r 207 / (699, 256) r 208.5 at 960x480"}
    runs = [("now", refine_files)]
    if old_rev:
        runs.insert(0, (f"before ({old_rev})", old_overlap(old_rev).refine_files))
    for name, fn in runs:
        s = fn([src], "theta-v", tmp / f"gear-{name[:3]}.json")
        prof = load_profile(tmp / f"gear-{name[:3]}.json")
        out[name] = {
            "seam_error_before": round(seam_of(src, load_profile("theta-v")), 4),
            "seam_error_after": round(seam_of(src, prof), 4),
            "seam_mad_before": s["seam_mad_before"],
            "seam_mad_after": s["seam_mad_after"],
            "center_shift_px_at_5792": [round(math.hypot(*c), 1) for c in s["center_shift_px"]],
            "back_rotation_change_deg": round(s["back_rotation_change_deg"], 2),
            "refused": s.get("refused"),
            "warnings": [w.split(":")[0] for w in s.get("warnings", [])],
        }
        print(name, json.dumps(out[name]), flush=True)
    fit = fit_dual_fisheye(read_linear(src)[0], 0.98)
    out["calibrate fisheye"] = {
        "family": fit.family,
        "fov_deg": round(2 * fit.half_fov_deg, 2),
        "layout": fit.layout,
        "center_error_px": [
            round(math.dist((l.center[0], l.center[1]), (c.cx, c.cy)), 3) for l, c in zip(fit.profile.lenses, GEAR)
        ],
        "seam_error": round(fit.seam_final["seam_error"], 4),
    }
    print("fisheye", json.dumps(out["calibrate fisheye"]), flush=True)
    return out


def real_frames(tmp: Path) -> dict:
    src = REAL / "theta_s_dualfisheye" / "thetaS_dualfisheye_raw_1920x1080.jpg"
    out = {}
    t0 = time.perf_counter()
    fit, s = fit_file(src, tmp / "ts.json")
    out["calibrate fisheye"] = {
        k: s[k]
        for k in (
            "layout",
            "family",
            "fov_deg",
            "circles",
            "back_ypr_deg",
            "seam_error_start",
            "seam_error_refined",
            "seam_error",
            "refusal",
            "shipped_profiles_seam_error",
        )
    }
    out["calibrate fisheye"]["seconds"] = round(time.perf_counter() - t0, 1)
    s = refine_files([src], "theta-s-video", tmp / "ts-unit.json")
    out["calibrate overlap --base theta-s-video"] = {
        k: s[k]
        for k in ("seam_error_before", "seam_error_after", "refused", "center_shift_px", "back_rotation_change_deg")
    }
    img, sat = read_input(src)
    prof = load_profile("theta-s-video")
    rep, w = check_profile_fit(img, prof, sat)
    w += check_upright(unwarp_srgb8(img, prof, 512), rep)
    out["unwarp --profile theta-s-video"] = {"report": rep, "warnings": [x.split(":")[0] for x in w]}
    turned = cv2.imread(str(src))
    for (cx, cy), t in (((461, 481), cv2.ROTATE_90_CLOCKWISE), ((1456, 470), cv2.ROTATE_90_COUNTERCLOCKWISE)):
        turned[cy - 460 : cy + 460, cx - 460 : cx + 460] = cv2.rotate(
            turned[cy - 460 : cy + 460, cx - 460 : cx + 460].copy(), t
        )
    turned = cv2.cvtColor(turned, cv2.COLOR_BGR2RGB)
    rep, w = check_profile_fit(turned, prof, sat)
    w += check_upright(unwarp_srgb8(turned, prof, 512), rep)
    out["circles turned by 90°, unwarp --profile theta-s-video"] = {
        "report": rep,
        "warnings": [x.split(":")[0] for x in w],
    }
    print(json.dumps(out, default=str), flush=True)
    return out


def warning_table(panos) -> list[dict]:
    rows = []
    theta = load_profile("theta-v")
    size = (1152, 576)
    tv = theta.scaled(*size)

    def add(kind, correct, name, image, prof, sat=0.98):
        rep, warns = check_profile_fit(image, prof, sat)
        rows.append(
            {
                "kind": kind,
                "correct": correct,
                "case": name,
                "seam_error": rep["seam_error"],
                "warns": [w.split(":")[0] for w in warns],
            }
        )
        print(rows[-1], flush=True)

    def moved(prof, back_deg=0.0, centre_frac=0.0, fov_scale=1.0):
        R = np.asarray(rotation_z(0.0))
        from solidkit.camera.lens import rotation_to_ypr_deg
        from solidkit.envmap.coords import rotation_from_ypr

        lenses = list(prof.lenses)
        if back_deg:
            R = np.asarray(rotation_from_ypr(math.radians(back_deg), 0.0, 0.0))
            lenses[1] = lenses[1].model_copy(update={"ypr_deg": rotation_to_ypr_deg(R @ lenses[1].rotation)})
        if centre_frac:
            d = centre_frac * lenses[0].max_radius()
            lenses[0] = lenses[0].model_copy(update={"center": (lenses[0].center[0] + d, lenses[0].center[1])})
        if fov_scale != 1.0:
            lenses = [l.model_copy(update={"poly": [k * fov_scale for k in l.poly]}) for l in lenses]
        return prof.model_copy(update={"lenses": lenses})

    for scene in ("city", "courtyard", "sunrise"):
        img = to_uint8(render_fisheye(panos[scene], tv, size))
        add("rendered Theta V", True, f"{scene}: theta-v", img, theta)
        for deg in (1.0, 2.0, 4.0, 8.0):
            add("rendered Theta V", False, f"{scene}: back lens {deg:g}° off", img, moved(theta, back_deg=deg))
        add(
            "rendered Theta V",
            False,
            f"{scene}: front centre 3 % of the radius off",
            img,
            moved(theta, centre_frac=0.03),
        )
        add("rendered Theta V", False, f"{scene}: r(theta) 3 % too large", img, moved(theta, fov_scale=1.03))
        other = to_uint8(camera_frame(panos[scene], truth_profile("equidistant", 97.5, circles=GEAR), SIZE))
        add("another camera", False, f"{scene}: Gear-like equidistant 195° frame with theta-v", other, theta)
        right = truth_profile("equidistant", 97.5, circles=GEAR)
        add("another camera", True, f"{scene}: the same frame with its true profile", other, right)
    for jpg in sorted((REPO / "solidkit" / "assets" / "campaign_mini" / "card").rglob("R*.JPG")):
        img, sat = read_input(jpg)
        if img.shape[1] != 2 * img.shape[0]:
            continue
        add("virtual campaign Theta V JPEG (1920x960)", True, jpg.relative_to(REPO).as_posix(), img, theta, sat)
    src = REAL / "theta_s_dualfisheye" / "thetaS_dualfisheye_raw_1920x1080.jpg"
    img, sat = read_input(src)
    add("real Theta S frame", True, "theta-s-video", img, load_profile("theta-s-video"), sat)
    for deg in (2.0, 4.0):
        add(
            "real Theta S frame",
            False,
            f"theta-s-video, back lens {deg:g}° off",
            img,
            moved(load_profile("theta-s-video"), back_deg=deg),
            sat,
        )
    return rows


def upright_table(panos) -> list[dict]:
    rows = []
    for scene in ("city", "courtyard", "sunrise"):
        x = cv2.resize(panos[scene], (512, 256), interpolation=cv2.INTER_AREA)
        for roll in (0.0, 90.0, -90.0):
            p = np.asarray(rotate(x, rotation_z(math.radians(-roll))), np.float32) if roll else x
            e = upright_of_panorama(to_uint8(p))
            rows.append(
                {
                    "panorama": f"{scene} (real HDR, tonemapped)",
                    "turned_deg": roll,
                    "found_roll_deg": e.roll_deg,
                    "margin": round(e.margin, 3),
                    "confident": e.confident,
                    "ok": e.roll_deg == roll,
                }
            )
    src = REAL / "theta_s_dualfisheye" / "thetaS_dualfisheye_raw_1920x1080.jpg"
    img, _ = read_input(src)
    pano = unwarp_srgb8(img, load_profile("theta-s-video"), 512)
    for roll in (0.0, 90.0, -90.0):
        p = np.asarray(rotate(pano.astype(np.float32), rotation_z(math.radians(-roll))), np.float32) if roll else pano
        e = upright_of_panorama(np.clip(p, 0, 255).astype(np.uint8))
        rows.append(
            {
                "panorama": "real Theta S kitchen via theta-s-video",
                "turned_deg": roll,
                "found_roll_deg": e.roll_deg,
                "margin": round(e.margin, 3),
                "confident": e.confident,
                "ok": e.roll_deg == roll,
            }
        )
    for r in rows:
        print(r, flush=True)
    return rows


def markdown(res: dict) -> str:
    L = [
        "# Any dual-fisheye camera from one frame",
        "",
        f"Run {res['date']} on {res['machine']} (load average {res['load']}); `benchmarks/bench_selfcal.py`. "
        "Frames rendered from the real CC0 HDR panoramas with solidkit's forward model, 8-bit sRGB.",
        "",
        "## 1. Recovered vs truth (`calibrate fisheye`, refinement on, 960x480 / 480x960)",
        "",
        "| scene | truth family, fov, layout, back-lens aim | found family, fov | layout | centre err px | back-lens "
        "err ° | seam start → refined (kept) | s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in res["recovery"]:
        t = r["truth"]
        L.append(
            f"| {r['scene']} | {t['family']} {t['fov_deg']:.0f}°, {t['arrangement']}, roll {t['roll_deg']:+.0f}°, "
            f"aim {t['back_aim_offset_deg']} | {r['family']}{'' if r['family_ok'] else ' ✗'} {r['fov_deg']:.2f}° "
            f"({r['fov_error_deg']:+.2f}) | {r['layout']}{'' if r['layout_ok'] else ' ✗'} | "
            f"{', '.join(f'{c:.2f}' for c in r['center_error_px'])} | {r['back_rotation_error_deg']:.2f} | "
            f"{r['seam_error_start']:.3f} → {r['seam_error_refined']:.3f}{' refused' if r['refused'] else ''} "
            f"({r['seam_error_kept']:.3f}) | {r['seconds']} |"
        )
    g = res["gear"]
    L += [
        "",
        "## 2. Refinement from another camera's profile (`calibrate overlap --base theta-v` on a Gear-like frame)",
        "",
        g["frame"],
        "",
        "| code | seam error before → after | linear seam MAD before → after | centre shifts (px at 5792) | back lens "
        "change ° | refused | warnings |",
        "|---|---|---|---|---|---|---|",
    ]
    for k, v in g.items():
        if isinstance(v, dict) and "center_shift_px_at_5792" in v:
            L.append(
                f"| {k} | {v['seam_error_before']:.3f} → {v['seam_error_after']:.3f} | {v['seam_mad_before']:.4f} → "
                f"{v['seam_mad_after']:.4f} | {v['center_shift_px_at_5792']} | {v['back_rotation_change_deg']} | "
                f"{'yes' if v['refused'] else 'no'} | {', '.join(v['warnings']) or '-'} |"
            )
    f = g["calibrate fisheye"]
    L += [
        "",
        f"`calibrate fisheye` on the same frame: {f['family']} {f['fov_deg']}° (truth equidistant 195°), "
        f"{f['layout']}, centres {f['center_error_px']} px from truth, seam error {f['seam_error']}.",
        "",
        "## 3. Real Theta S live frame (1920x1080, indoor kitchen: objects within a metre)",
        "",
    ]
    rf = res["real"]
    c = rf["calibrate fisheye"]
    L += [
        f"- `calibrate fisheye`: layout **{c['layout']}**, {c['family']} {c['fov_deg']}°, back lens ypr "
        f"{c['back_ypr_deg']}, seam error start {c['seam_error_start']:.3f} → refined {c['seam_error_refined']:.3f} → "
        f"kept {c['seam_error']:.3f}{' (refinement refused)' if c['refusal'] else ''}; the shipped theta-s-video "
        f"profile (refined unbounded on this very frame) scores {c['shipped_profiles_seam_error']}, listed in the "
        f"summary ({c['seconds']} s at this load).",
        "- `calibrate overlap --base theta-s-video`: seam error "
        f"{rf['calibrate overlap --base theta-s-video']['seam_error_before']:.3f} → "
        f"{rf['calibrate overlap --base theta-s-video']['seam_error_after']:.3f}, refused: "
        f"{rf['calibrate overlap --base theta-s-video']['refused'] or 'no'}.",
        "- `capture unwarp --profile theta-s-video`: seam error "
        f"{rf['unwarp --profile theta-s-video']['report']['seam_error']}, roll "
        f"{rf['unwarp --profile theta-s-video']['report'].get('roll_deg')}, warnings "
        f"{rf['unwarp --profile theta-s-video']['warnings'] or 'none'}.",
        f"- the frame with its circles turned by 90°, same profile: seam error "
        f"{rf['circles turned by 90°, unwarp --profile theta-s-video']['report']['seam_error']}, warnings "
        f"{rf['circles turned by 90°, unwarp --profile theta-s-video']['warnings']}.",
        "",
        f"## 4. The warning: seam errors of correct and wrong profiles (threshold {SEAM_ERROR_WARN})",
        "",
        "| kind | case | correct profile | seam error | warns |",
        "|---|---|---|---|---|",
    ]
    for r in res["warning"]:
        seam = "unmeasured" if r["seam_error"] is None else r["seam_error"]
        L.append(
            f"| {r['kind']} | {r['case']} | {'yes' if r['correct'] else 'no'} | {seam} | "
            f"{', '.join(r['warns']) or 'no'} |"
        )
    ok = [r["seam_error"] for r in res["warning"] if r["correct"] and r["seam_error"] is not None]
    bad = [r["seam_error"] for r in res["warning"] if not r["correct"] and r["seam_error"] is not None]
    n_ok = sum(r["correct"] for r in res["warning"])
    n_ok_warn = sum(bool(r["warns"]) for r in res["warning"] if r["correct"])
    n_bad_warn = sum(bool(r["warns"]) for r in res["warning"] if not r["correct"])
    n_bad = len(res["warning"]) - n_ok
    L += [
        "",
        f"Warnings: {n_ok_warn} of {n_ok} correct profiles (false alarms), {n_bad_warn} of {n_bad} wrong ones. "
        "Unmeasured: the dark 1/25000 s sun frames of the campaign (no warning) and profiles whose overlap ring "
        "falls on black outside the image circles (warned).",
        f"Correct profiles: max {max(ok):.3f}; wrong profiles: min {min(bad):.3f}. " + res["threshold_note"],
        "",
        f"## 5. Which way is up (layout check on the unwarped panorama; confident at margin ≥ {CONFIDENT_MARGIN})",
        "",
        "| panorama | turned by | found | margin | confident | right |",
        "|---|---|---|---|---|---|",
    ]
    for r in res["upright"]:
        L.append(
            f"| {r['panorama']} | {r['turned_deg']:+.0f}° | {r['found_roll_deg']:+.0f}° | {r['margin']} | "
            f"{'yes' if r['confident'] else 'no'} | {'yes' if r['ok'] else '**no**'} |"
        )
    return "\n".join(L) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--old",
        default=None,
        help="git revision of calibration/overlap.py before the fit of lens families (e.g. e573428~1)",
    )
    args = ap.parse_args()
    import os

    panos = {n: panorama(n) for n in ("city", "courtyard", "sunrise")}
    res = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "machine": platform.platform(),
        "load": round(os.getloadavg()[0], 1),
    }
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        res["warning"] = warning_table(panos)
        res["upright"] = upright_table(panos)
        res["gear"] = gear_case(panos, tmp, args.old)
        res["real"] = real_frames(tmp)
        res["recovery"] = recovery(panos)
    ok = [r["seam_error"] for r in res["warning"] if r["correct"] and r["seam_error"] is not None]
    bad = [r["seam_error"] for r in res["warning"] if not r["correct"] and r["seam_error"] is not None]
    res["threshold_note"] = (
        f"The threshold {SEAM_ERROR_WARN} sits above the worst correct profile ({max(ok):.3f}: the real "
        f"indoor frame, parallax); {sum(b <= SEAM_ERROR_WARN for b in bad)} of {len(bad)} measured wrong "
        "profiles stay below it: back lens 1-4° off, a centre 3 % off on the textureless sunrise "
        "horizon, and on the real frame (whose parallax already costs 0.6) the back lens 2-4° off."
    )
    OUT.mkdir(exist_ok=True)
    (OUT / "selfcal.json").write_text(json.dumps(res, indent=1, default=str))
    (OUT / "selfcal.md").write_text(markdown(res))
    print(markdown(res))


if __name__ == "__main__":
    main()
