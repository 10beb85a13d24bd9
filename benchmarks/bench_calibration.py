"""Calibration accuracy against named peers, measured in the same run.

- colour: our white balance + CCM vs LibRaw's built-in camera matrix (rawpy sRGB output, camera
  white balance; also with the chart-grey white balance) on the real ColorChecker DNG:
  mean CIEDE2000 over the 24 patches (peers exposure-matched by one least-squares scalar).
- response: Debevec (default) vs OpenCV's Robertson on synthetic brackets with a known curve:
  max |log2 error| over codes 10..245.
- fisheye: Kannala-Brandt vs Mei held-out RMS (leave-k-out) on the real 15-view checkerboard set.

Writes benchmarks/results/calibration.json and .md. Real-data parts are skipped (reported as such)
when ../shared/data/real is absent.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
REAL = (ROOT / ".." / "shared" / "data" / "real").resolve()
OUT = ROOT / "benchmarks" / "results"
# corner-patch centres (dark skin, bluish green, black, white) of the real chart, read off the image once
DNG_CORNERS = [[721, 626], [1256, 611], [1258, 926], [701, 930]]


def bench_colour() -> dict:
    import rawpy

    from solidkit.calibration.colour import (
        calibrate_colour,
        chart_homography_from_corners,
        delta_e2000,
        fit_white_balance,
        read_linear_image,
        reference_linear_srgb,
        sample_patches,
    )

    path = REAL / "raw_dng" / "colorchart.dng"
    if not path.is_file():
        return {"skipped": f"{path} absent"}
    corners = np.array(DNG_CORNERS, float)
    ours = calibrate_colour(read_linear_image(path), corners=corners)
    ref = reference_linear_srgb()
    H = chart_homography_from_corners(corners)
    with rawpy.imread(str(path)) as raw:
        rgb = raw.postprocess(
            gamma=(1, 1), no_auto_bright=True, output_bps=16, output_color=rawpy.ColorSpace.sRGB, use_camera_wb=True
        )
    m, _ = sample_patches(rgb.astype(np.float32) / 65535, H)

    def de(x):
        s = (x * ref).sum() / (x * x).sum()
        return float(delta_e2000(x * s, ref).mean())

    peer = de(m)
    peer_wb = de(m * fit_white_balance(m, ref))
    o = ours.residuals["ciede2000_mean"]["ccm"]
    return {
        "metric": "mean CIEDE2000 over 24 patches (lower is better)",
        "ours_wb_ccm": o,
        "libraw_camera_matrix": peer,
        "libraw_camera_matrix_plus_grey_wb": peer_wb,
        "ratio_ours_over_libraw_plus_grey_wb": o / peer_wb,
    }


def bench_response() -> dict:
    from solidkit.calibration.response import calibrate_response

    codes = np.arange(256) / 255.0
    curves = {
        "gamma2.2": (lambda x: np.clip(x, 0, None) ** (1 / 2.2), codes**2.2),
        "reinhard": (lambda x: x / (x + 0.18), 0.18 * codes / np.maximum(1 - codes, 1e-9)),
    }
    times = np.array([1 / 16, 1 / 4, 1, 4])
    rng = np.random.default_rng(0)
    radiance = 2.0 ** (rng.uniform(-9, 3, (120, 160, 1)) + np.array([0.0, 0.3, -0.3]))
    out = {"metric": "max |log2 error| (stops), codes 10..245 (lower is better)"}
    for name, (fwd, inv) in curves.items():
        imgs = [np.clip(np.round(255 * np.clip(fwd(radiance * t), 0, 1)), 0, 255).astype(np.uint8) for t in times]
        truth = (inv / inv[128])[10:246, None]
        row = {}
        for method in ("debevec", "robertson"):
            t0 = time.perf_counter()
            c = calibrate_response(imgs, times, method=method)
            row[method] = float(np.abs(np.log2(c[10:246] / truth)).max())
            row[f"{method}_seconds"] = time.perf_counter() - t0
        row["ratio_debevec_over_opencv_robertson"] = row["debevec"] / row["robertson"]
        out[name] = row
    return out


def bench_fisheye() -> dict:
    from solidkit.calibration.boards import detect_views
    from solidkit.calibration.fisheye import calibrate_fisheye

    paths = sorted((REAL / "fisheye_chessboard").glob("*.jpg"))
    if not paths:
        return {"skipped": "fisheye_chessboard absent"}
    prof = calibrate_fisheye(detect_views(paths, (6, 9)), (6, 9))
    kb, mei = prof.models["kb"], prof.models["mei"]
    return {
        "metric": "RMS reprojection (px); held-out = leave-k-views-out (lower is better)",
        "views": len(paths),
        "kb_fit": kb["rms_px"],
        "kb_held_out": kb["held_out"]["rms_px"],
        "mei_fit": mei["rms_px"],
        "mei_held_out": mei["held_out"]["rms_px"],
        "chosen": prof.chosen_model,
        "ratio_mei_over_kb_held_out": mei["held_out"]["rms_px"] / kb["held_out"]["rms_px"],
    }


def main() -> None:
    results = {"colour": bench_colour(), "response": bench_response(), "fisheye": bench_fisheye()}
    OUT.mkdir(parents=True, exist_ok=True)
    from solidkit.fsutil import atomic_write_text

    atomic_write_text(OUT / "calibration.json", json.dumps(results, indent=2) + "\n")
    lines = ["# Calibration accuracy vs peers", ""]
    for part, res in results.items():
        lines.append(f"## {part}")
        lines.append("")
        lines.append("```json")
        lines.append(json.dumps(res, indent=2))
        lines.append("```")
        lines.append("")
    atomic_write_text(OUT / "calibration.md", "\n".join(lines))
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
