"""Benchmark: the seam disparity (degrees) of right and wrong dual-fisheye profiles, and what ``calibrate fisheye``
fits, on rendered frames with known lenses and on the real Theta S frame.

Rendered frames: the bundled city.exr (tonemapped) through known lenses at 1280x640 (a Gear 360 frame halved), 8-bit
sRGB: a Gear-360-like equidistant 195° pair, a Theta-like pair (Ricoh's lens table, 200°) and the Gear-like pair with
the back lens 2° off opposite. Each is judged under its true profile and under wrong ones (a field 1.5° off, another
family, the back lens pitched 8.8° as a real Gear 360 fit once had it, the 2° assumed away), with the seam error
beside (:func:`solidkit.calibration.seam.seam_error`, 0 = agree, 1 = unrelated); then
:func:`solidkit.calibration.lensfit.fit_dual_fisheye` (no refinement) fits each frame. The real frame
(``../shared/data/real/theta_s_dualfisheye``, indoor, no truth) under the shipped ``theta-s-video`` profile and
under what ``calibrate fisheye`` fits (back lens within 3° of opposite, the default).
Writes benchmarks/results/seam_disparity.json and .md. Run: ``.venv/bin/python benchmarks/bench_seam_disparity.py``.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real" / "theta_s_dualfisheye" / "thetaS_dualfisheye_raw_1920x1080.jpg"
SIZE = (1280, 640)


def main() -> int:
    sys.path.insert(0, str(REPO))
    from solidkit.calibration.circles import Circle, find_image_circles
    from solidkit.calibration.disparity import DISPARITY_WARN_DEG, seam_disparity
    from solidkit.calibration.lensfit import back_tilt_deg, fit_dual_fisheye, start_profile
    from solidkit.calibration.seam import prepare_seam_image, seam_error
    from solidkit.camera.dualfisheye import read_linear
    from solidkit.camera.lens import load_profile
    from solidkit.capture.unwarp import render_fisheye
    from solidkit.envmap.io import imread, read_exr, srgb_decode, srgb_encode, tonemap
    from solidkit.envmap.sun import luminance

    pano, _ = read_exr(REPO / "solidkit" / "assets" / "hdr_panoramas" / "city.exr")
    city = np.clip(tonemap(pano), 0, 1).astype(np.float32)
    circles = [Circle(318.3, 322.2, 300.0, 1.0), Circle(959.6, 318.4, 298.0, 1.0)]

    def lenses(family, half_fov, offset=(0.0, 0.0)):
        p = start_profile(circles, SIZE, family, half_fov, back_offset_deg=offset)
        return p.model_copy(update={"lenses": [l.model_copy(update={"max_angle_deg": half_fov}) for l in p.lenses]})

    def frame(profile):
        fish = render_fisheye(city, profile, SIZE)
        return (np.clip(np.asarray(srgb_encode(fish)), 0, 1) * 255 + 0.5).astype(np.uint8)

    def judge(img, profile, circ, radius):
        t = time.perf_counter()
        d = seam_disparity(img, profile, circ)
        dt = time.perf_counter() - t
        lin = np.asarray(srgb_decode(img.astype(np.float32) / 255.0), np.float32)
        se = seam_error(prepare_seam_image(lin, radius, 0.98), profile.scaled(img.shape[1], img.shape[0]))
        return {**d.to_json(), "seam_error": round(float(se["seam_error"]), 4), "seconds": round(dt, 2)}

    frames = {
        "gear-like equidistant 195°": (
            lenses("equidistant", 97.5),
            {
                "field 1.5° narrow (193.5°)": lenses("equidistant", 96.75),
                "Ricoh's lens table (theta family)": lenses("theta", 97.5),
                "back lens pitched 8.8°": lenses("equidistant", 97.5, (0.0, 8.8)),
                "back lens pitched 2°": lenses("equidistant", 97.5, (0.0, 2.0)),
                "back lens yawed 1°": lenses("equidistant", 97.5, (1.0, 0.0)),
            },
        ),
        "theta-like lens table 200°": (lenses("theta", 100.0), {"equidistant 200°": lenses("equidistant", 100.0)}),
        "back lens 2° off opposite": (
            lenses("equidistant", 97.5, (2.0, 0.0)),
            {"back lens assumed opposite": lenses("equidistant", 97.5)},
        ),
    }
    results: dict = {"machine": f"{platform.platform()}, {os.cpu_count()} CPUs", "load_before": os.getloadavg()}
    rows = []
    fits = []
    for name, (truth, wrong) in frames.items():
        img = frame(truth)
        rows.append({"frame": name, "profile": "true", **judge(img, truth, circles, 300.0)})
        for wname, w in wrong.items():
            rows.append({"frame": name, "profile": wname, **judge(img, w, circles, 300.0)})
        t = time.perf_counter()
        fit = fit_dual_fisheye(np.asarray(srgb_decode(img / 255.0), np.float32), 0.98, refine=False)
        fits.append(
            {
                "frame": name,
                "family": fit.family,
                "fov_deg": round(2 * fit.half_fov_deg, 2),
                "back_tilt_deg": round(back_tilt_deg(fit.profile), 3),
                "true_back_tilt_deg": round(back_tilt_deg(truth), 3),
                "disparity": fit.disparity.to_json() if fit.disparity else None,
                "seconds": round(time.perf_counter() - t, 1),
            }
        )
    if REAL.exists():
        img = imread(REAL)[..., ::-1].copy()  # RGB
        lin, sat = read_linear(REAL)  # as `calibrate fisheye` reads it
        circ, _ = find_image_circles(luminance(lin))
        rows.append(
            {
                "frame": "real Theta S (indoor)",
                "profile": "theta-s-video (shipped)",
                **judge(img, load_profile("theta-s-video"), circ, 458.0),
            }
        )
        t = time.perf_counter()
        fit = fit_dual_fisheye(lin, sat)
        rows.append(
            {
                "frame": "real Theta S (indoor)",
                "profile": f"calibrate fisheye: {fit.family} {2 * fit.half_fov_deg:.1f}°, back lens "
                f"{back_tilt_deg(fit.profile):.2f}° off ({time.perf_counter() - t:.0f} s)",
                **judge(img, fit.profile, circ, 458.0),
            }
        )
    results.update(rows=rows, fits=fits, warn_deg=DISPARITY_WARN_DEG, load_after=os.getloadavg())
    OUT.mkdir(exist_ok=True)
    (OUT / "seam_disparity.json").write_text(json.dumps(results, indent=1, default=str) + "\n")
    lines = [
        "# Seam disparity of right and wrong profiles (degrees between the two lenses' views of one scene point)",
        "",
        f"Machine: {results['machine']}; load average before {tuple(round(x, 1) for x in results['load_before'])} "
        "(shared machine: the seconds are inflated). Rendered frames 1280x640 from city.exr; "
        f"`calibrate fisheye` warns above a median of {DISPARITY_WARN_DEG:g}° (or half the matches beyond 1°).",
        "",
        "| frame | profile | median (°) | p95 (°) | > 1° | matches | ring coverage | textured | seam error | s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:

        def f(v, spec=".2f"):
            return "-" if v is None else format(v, spec)

        lines.append(
            f"| {r['frame']} | {r['profile']} | {f(r['median_deg'])} | {f(r['p95_deg'])} | "
            f"{f(r['doubled_fraction'], '.0%')} | {r['matches']} | {f(r['coverage'], '.0%')} | "
            f"{f(r['textured_fraction'], '.0%')} | {f(r['seam_error'], '.3f')} | {r['seconds']} |"
        )
    lines += [
        "",
        "What `fit_dual_fisheye` (no refinement) finds on the rendered frames:",
        "",
        "| frame | family | field (°) | back lens off opposite (°): fit / truth | median disparity (°) | s |",
        "|---|---|---|---|---|---|",
    ]
    for r in fits:
        med = r["disparity"]["median_deg"] if r["disparity"] else None
        lines.append(
            f"| {r['frame']} | {r['family']} | {r['fov_deg']} | {r['back_tilt_deg']} / {r['true_back_tilt_deg']} | "
            f"{med} | {r['seconds']} |"
        )
    lines += [
        "",
        "Doubled content shows as its own angle: a field 1.5° narrow doubles the seam by ~1.4°, another lens family "
        "by 6-7°, a back lens 2° off by 2° (across the ring; along it 0). The p95 of a right profile is the few "
        "matches of repeated texture (windows) to their neighbours. The seam error, a photometric ratio on the "
        "overlap ring, ranks these too but without a unit, and on a real Gear 360 frame a wrong fit scored better "
        "than a right one (its band was narrow).",
    ]
    (OUT / "seam_disparity.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
