"""Benchmark: the residual-tilt estimator (:func:`solidkit.envmap.tilt.residual_tilt`) against known tilts.

Truth: rendered level street panoramas (tests/data/level_street_{0,1,2}.jpg, 1024x512, and
level_street_3_1024.jpg, 2048x1024; the synth scene frame is level by construction; rendered by
tests/data/make_tilt_fixtures.py), plus any ``--extra`` renders of the same kind, each as rendered
and rotated by known (yaw, pitch, roll) (uniform: yaw ±180°, pitch and roll ±4°, seed 5; cubic
resampling). Error: the angle between the estimated and the true gravity. The 2048x1024 renders are
measured at their size (the default ``max_height`` 1024) and reduced to 512. The shared Theta S
stitched still (Jobsite1, no truth) is reported as stored, after applying its recorded pose, and after
levelling by its own estimate. Goal: error below 0.2° on rendered panoramas.
Writes benchmarks/results/tilt.json and tilt.md. Run: ``.venv/bin/python benchmarks/bench_tilt.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from solidkit.envmap.coords import angular_distance, rotation_from_ypr
from solidkit.envmap.resample import rotate
from solidkit.envmap.tilt import residual_tilt

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results"
DATA = REPO / "tests" / "data"
REAL = REPO.parent / "shared" / "data" / "real" / "theta_s_equirect" / "Jobsite1.JPG"
E_Y = np.array([0.0, 1.0, 0.0])


def errors(
    img: np.ndarray, tilts: list[tuple[float, float, float]], max_height: int
) -> tuple[list[float], list[float]]:
    errs, secs = [], []
    for ypr in tilts:
        Rt = np.asarray(rotation_from_ypr(*np.radians(ypr)))
        im = img if not any(ypr) else np.clip(rotate(img.astype(np.float32), Rt, "cubic"), 0, 255).astype(np.uint8)
        t0 = time.perf_counter()
        est = residual_tilt(im, max_height=max_height)
        secs.append(time.perf_counter() - t0)
        errs.append(math.degrees(float(angular_distance(np.asarray(est.gravity), Rt @ E_Y))))
    return errs, secs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tilts", type=int, default=8, help="random tilts per panorama (plus the level one)")
    ap.add_argument("--extra", type=Path, nargs="*", default=[], help="more level renders (make_tilt_fixtures.py)")
    args = ap.parse_args()
    rng = np.random.default_rng(5)
    tilts = [(0.0, 0.0, 0.0)] + [
        (rng.uniform(-180, 180), rng.uniform(-4, 4), rng.uniform(-4, 4)) for _ in range(args.tilts)
    ]
    files = [DATA / f"level_street_{k}.jpg" for k in range(3)] + [DATA / "level_street_3_1024.jpg"] + list(args.extra)
    rows = []
    for f in files:
        img = cv2.imread(str(f))[..., ::-1].copy()
        for mh in [img.shape[0], 512] if img.shape[0] > 512 else [512]:
            errs, secs = errors(img, tilts, mh)
            rows.append(
                {
                    "panorama": f.name,
                    "height": img.shape[0],
                    "measured_at": mh,
                    "errors_deg": errs,
                    "median_deg": float(np.median(errs)),
                    "max_deg": float(max(errs)),
                    "seconds_median": float(np.median(secs)),
                }
            )
            print(
                f"{f.name} at {mh}: median {rows[-1]['median_deg']:.3f}°, max {rows[-1]['max_deg']:.3f}°",
                file=sys.stderr,
            )
    out: dict = {"machine": f"{platform.platform()}, {os.cpu_count()} CPUs", "tilts": tilts, "rows": rows}
    for label, sel in (
        ("512 px high", lambda r: r["measured_at"] == 512),
        ("1024 px high", lambda r: r["measured_at"] == 1024),
    ):
        e = [x for r in rows if sel(r) for x in r["errors_deg"]]
        if e:
            out[f"all {label}"] = {
                "cases": len(e),
                "median_deg": float(np.median(e)),
                "max_deg": float(max(e)),
                "within_0p2": int(sum(x < 0.2 for x in e)),
            }
    if REAL.is_file():
        from solidkit.camera.metadata import read_metadata

        meta = read_metadata(REAL)
        small = cv2.resize(cv2.imread(str(REAL))[..., ::-1], (2048, 1024), interpolation=cv2.INTER_AREA)
        stored = residual_tilt(small)
        R_pose = np.asarray(rotation_from_ypr(0.0, math.radians(meta.pitch_deg), math.radians(meta.roll_deg)))
        posed = residual_tilt(np.clip(rotate(small.astype(np.float32), R_pose, "cubic"), 0, 255).astype(np.uint8))
        R_own = np.asarray(rotation_from_ypr(0.0, math.radians(stored.pitch_deg), math.radians(stored.roll_deg)))
        own = residual_tilt(np.clip(rotate(small.astype(np.float32), R_own, "cubic"), 0, 255).astype(np.uint8))
        out["theta_s_still"] = {
            "recorded_pitch_roll_deg": [meta.pitch_deg, meta.roll_deg],
            "stored": stored.to_json(),
            "after_recorded_pose": posed.to_json(),
            "after_own_estimate": own.to_json(),
        }
    (OUT / "tilt.json").write_text(json.dumps(out, indent=1) + "\n")
    lines = [
        "# Residual tilt of rendered panoramas with known tilts",
        "",
        f"Machine: {out['machine']}. Cases per panorama: level + {args.tilts} random tilts (yaw ±180°, pitch/roll ±4°, "
        "seed 5).",
        "Error = angle between the estimated and the true gravity (degrees). Goal: < 0.2°.",
        *(
            [
                f"Extra renders (tests/data/make_tilt_fixtures.py, H=1024, not in the repo): "
                f"{', '.join(p.name for p in args.extra)}."
            ]
            if args.extra
            else []
        ),
        "",
        "| panorama | size | measured at (px high) | median (°) | max (°) | time per estimate (s) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['panorama']} | {2 * r['height']}x{r['height']} | {r['measured_at']} | {r['median_deg']:.3f} | "
            f"{r['max_deg']:.3f} | {r['seconds_median']:.2f} |"
        )
    lines.append("")
    for k, v in out.items():
        if k.startswith("all "):
            lines.append(
                f"- {k}: {v['cases']} cases, median {v['median_deg']:.3f}°, max {v['max_deg']:.3f}°, "
                f"{v['within_0p2']}/{v['cases']} below 0.2°."
            )
    lines += [
        "",
        "The estimator's earlier end-point noise model (sigma ∝ 1/length) on the same kind of cases: "
        "level_street_3_1024 0.34° off level and tilted (0.22-0.34°); the three 512-px streets median 0.07°, max "
        "0.28°. Cause: short segments outweighed the long edges (which are vertical to 0.01°); now a line-fit noise "
        "model (sigma ∝ length^-1.5) weights them by the precision their leans show.",
    ]
    if "theta_s_still" in out:
        t = out["theta_s_still"]
        lines += [
            "",
            f"Theta S stitched still (Jobsite1, 2048x1024; no truth): as stored {t['stored']['tilt_deg']:.2f}° ± "
            f"{t['stored']['uncertainty_deg']:.2f}°; after the recorded pose (pitch "
            f"{t['recorded_pitch_roll_deg'][0]:.1f}°, roll {t['recorded_pitch_roll_deg'][1]:.1f}°) "
            f"{t['after_recorded_pose']['tilt_deg']:.2f}°; after its own correction "
            f"{t['after_own_estimate']['tilt_deg']:.2f}° ± {t['after_own_estimate']['uncertainty_deg']:.2f}°.",
        ]
    (OUT / "tilt.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
