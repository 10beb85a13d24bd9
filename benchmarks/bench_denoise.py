"""Noise of rendered photos and source panoramas with and without Open Image Denoise, and render time per clean
sample.

Usage::

    DRJIT_NUM_THREADS=2 nice -n 10 .venv/bin/python benchmarks/bench_denoise.py [--ref-spp 1024] [--name NAME]

Cases: photos as ``solidkit synth dataset`` renders them (192x144, 60° FOV, master seed 7, samples 0 and 1)
and source panoramas as ``solidkit synth sources`` renders them (256x128, seed 7, sources 0 and 9). For each,
a reference of ``--ref-spp`` samples per pixel in two halves of different seeds, then plain renders at a few
spp (``path`` integrator, the pipeline's firefly treatment), and the same renders denoised (OIDN's ``RT``
filter, HDR, the sun's pixels kept as rendered) with three guide sets: none, albedo, albedo + normal (the
``aov`` integrator through the same camera rays). Errors are against the reference, on the paper's tonemap
(what the model sees):

- ``psnr_db``: PSNR over all pixels, and ``psnr_corrected_db`` with the reference's own noise taken out of the
  mean squared error (a quarter of the squared difference of its two halves);
- ``rel_mse``: relative MSE of the linear radiance, ``mean((x - r)^2 / (r^2 + 0.01))``;
- ``fireflies``: pixels whose tonemapped luminance exceeds the reference's by more than 0.2;
- ``gradient_ratio``: mean absolute pixel difference (tonemapped) over the reference's: above 1 noise, below 1
  detail smoothed away.

Time per clean sample: a denoised render costs the plain render, its guides and the filter. ``equivalent_spp``
is the spp the plain render needs for the denoised render's (corrected) error, from a power-law fit of the
plain renders' corrected MSE against spp (spp >= 8; extrapolated past the largest measured spp, flagged), and
``time_ratio`` = that cost / plain render at ``equivalent_spp`` (plain render time fitted as ``a + b spp``).
Writes ``benchmarks/results/denoise[-NAME].json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.envmap import tonemap
from solidkit.envmap.sun import LUMINANCE_WEIGHTS
from solidkit.synth.cameras import equirect_sensor, pinhole_sensor
from solidkit.synth.denoise import denoise_hdr, render_guides
from solidkit.synth.mitsuba_variant import mitsuba, variant
from solidkit.synth.panocrops import SourceConfig
from solidkit.synth.render import render_rgb
from solidkit.synth.sample import (
    Generator,
    SampleConfig,
    sun_mask_image,
    sun_mask_panorama,
    suppress_fireflies,
)
from solidkit.synth.scene import to_mitsuba

HERE = Path(__file__).resolve().parent
PLAIN_SPP = (4, 8, 16, 32, 64, 128, 256)
DENOISE_SPP = (4, 8, 16, 32)
GUIDES = ("none", "albedo", "albedo+normal")


def photo_case(seed: int, index: int) -> dict[str, Any]:
    gen = Generator(seed, SampleConfig(width=192, height=144))
    block, (cam, _) = gen.block_and_view(*divmod(index, 6))
    light = gen.lighting(index)
    scene = to_mitsuba(block, light.emitter(), tex_size=gen.config.tex_size)
    return {
        "name": f"photo seed {seed} sample {index}",
        "kind": "photo",
        "lighting": light.meta.get("kind"),
        "scene": scene,
        "sensor": lambda spp, s: pinhole_sensor(cam, spp=spp, seed=s),
        "max_depth": gen.config.max_depth,
        "protect": sun_mask_image(light.sun, cam),
        "wrap": False,
    }


def source_case(seed: int, index: int, height: int = 128) -> dict[str, Any]:
    from solidkit.synth.panocrops import source_setup

    cfg = SourceConfig(height=height)
    block, cam, light = source_setup(seed, index, cfg)
    scene = to_mitsuba(block, light.emitter(), tex_size=cfg.tex_size)
    return {
        "name": f"source seed {seed} index {index}",
        "kind": "source panorama",
        "lighting": light.meta.get("kind"),
        "scene": scene,
        "sensor": lambda spp, s: equirect_sensor(cam.position, np.eye(3), height, jitter=True, spp=spp, seed=s),
        "max_depth": cfg.max_depth,
        "protect": sun_mask_panorama(light.sun, np.eye(3), height),
        "wrap": True,
    }


def tm(x: np.ndarray) -> np.ndarray:
    return np.asarray(tonemap(x), np.float64)


def gradient_energy(a: np.ndarray) -> float:
    return float(np.mean(np.abs(np.diff(a, axis=0))) + np.mean(np.abs(np.diff(a, axis=1))))


def errors(x: np.ndarray, ref: np.ndarray, floor: float) -> dict[str, float]:
    a, r = tm(x), tm(ref)
    mse = float(np.mean((a - r) ** 2))
    corrected = max(mse - floor, 1e-12)
    lum = (a - r) @ LUMINANCE_WEIGHTS
    rel = float(np.mean((x.astype(np.float64) - ref) ** 2 / (ref.astype(np.float64) ** 2 + 0.01)))
    return {
        "gradient_ratio": gradient_energy(a) / gradient_energy(r),
        "psnr_db": -10 * math.log10(max(mse, 1e-12)),
        "psnr_corrected_db": -10 * math.log10(corrected),
        "mse_corrected": corrected,
        "rel_mse": rel,
        "fireflies": int((lum > 0.2).sum()),
    }


def run_case(case: dict[str, Any], ref_spp: int) -> dict[str, Any]:
    scene, sensor, depth, protect, wrap = (
        case["scene"],
        case["sensor"],
        case["max_depth"],
        case["protect"],
        case["wrap"],
    )

    def plain(spp: int, seed: int) -> tuple[np.ndarray, float]:
        t0 = time.perf_counter()
        img = render_rgb(scene, sensor(spp, seed), spp, max_depth=depth, seed=seed)
        img, _ = suppress_fireflies(img, protect, 10.0, wrap=wrap)
        return img, time.perf_counter() - t0

    render_rgb(scene, sensor(1, 99), 1, max_depth=depth, seed=99)  # compile the kernels outside the timings
    render_guides(scene, sensor(1, 99), 1, seed=99)
    half = ref_spp // 2
    ref_a, t_ref = plain(half, 1001)
    ref_b, _ = plain(half, 1002)
    ref = 0.5 * (ref_a + ref_b)
    floor = float(np.mean((tm(ref_a) - tm(ref_b)) ** 2)) / 4.0
    rows: list[dict[str, Any]] = []
    images = {}
    for spp in PLAIN_SPP:
        img, dt = plain(spp, 7 + spp)
        images[spp] = (img, dt)
        rows.append({"spp": spp, "denoise": False, "guides": None, "seconds": dt, **errors(img, ref, floor)})
    for spp in DENOISE_SPP:
        c, t_render = images[spp]  # the plain render is the denoiser's input
        t0 = time.perf_counter()
        albedo, normal = render_guides(scene, sensor(spp, 7 + spp), spp, seed=7 + spp)
        t_guides = time.perf_counter() - t0
        for g in GUIDES:
            t0 = time.perf_counter()
            out = denoise_hdr(
                c,
                None if g == "none" else albedo,
                normal if g == "albedo+normal" else None,
                protect=protect,
            )
            t_dn = time.perf_counter() - t0
            rows.append(
                {
                    "spp": spp,
                    "denoise": True,
                    "guides": g,
                    "seconds_render": t_render,
                    "seconds_guides": t_guides if g != "none" else 0.0,
                    "seconds_denoise": t_dn,
                    "seconds": t_render + (t_guides if g != "none" else 0.0) + t_dn,
                    **errors(out, ref, floor),
                }
            )
    plain_rows = [r for r in rows if not r["denoise"] and r["guides"] is None]
    fit_rows = [r for r in plain_rows if r["spp"] >= 8]
    slope, icept = np.polyfit(np.log([r["spp"] for r in fit_rows]), np.log([r["mse_corrected"] for r in fit_rows]), 1)
    tb, ta = np.polyfit([r["spp"] for r in plain_rows], [r["seconds"] for r in plain_rows], 1)
    for r in rows:
        if r["denoise"]:
            eq = float(math.exp((math.log(r["mse_corrected"]) - icept) / slope))
            r["equivalent_spp"] = eq
            r["equivalent_extrapolated"] = eq > max(PLAIN_SPP)
            r["time_ratio"] = r["seconds"] / (ta + tb * eq)
    return {
        "case": case["name"],
        "kind": case["kind"],
        "lighting": case["lighting"],
        "ref_spp": ref_spp,
        "ref_seconds_per_half": t_ref,
        "ref_noise_floor_mse": floor,
        "ref_noise_floor_psnr_db": -10 * math.log10(max(floor, 1e-12)),
        "plain_fit": {"mse_slope": float(slope), "seconds_a": float(ta), "seconds_per_spp": float(tb)},
        "rows": rows,
    }


def table(res: dict[str, Any]) -> str:
    lines = [
        "# Open Image Denoise on rendered photos and source panoramas",
        "",
        f"Machine: {res['machine']}, Mitsuba variant {res['variant']}, drjit threads as set by DRJIT_NUM_THREADS "
        f"({res['threads']}); niced beside a training job, so seconds are noisy and ratios are what to read.",
        f"Reference: {res['ref_spp']} spp in two halves; errors on the paper's tonemap (PSNR corrected for the "
        "reference's own noise); fireflies = pixels > 0.2 brighter than the reference (tonemapped luminance).",
        "Gradient ratio = mean absolute pixel difference over the reference's (> 1 noise, < 1 smoothed).",
        "Time ratio = (plain render + guides + denoise) / (plain render at the spp that reaches the same error); "
        f"OIDN's start-up, once per process, is left out ({res['oidn_init_seconds']:.1f} s).",
        "",
        "| case | lighting | render | spp | PSNR (dB) | PSNR corr. (dB) | rel. MSE | fireflies | gradient ratio "
        "| equiv. plain spp | time ratio |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in res["cases"]:
        for r in c["rows"]:
            what = f"OIDN, guides {r['guides']}" if r["denoise"] else (r["guides"] or "plain")
            eq = ""
            ratio = ""
            if r["denoise"]:
                eq = f"{r['equivalent_spp']:.0f}" + (" (extrap.)" if r["equivalent_extrapolated"] else "")
                ratio = f"{r['time_ratio']:.3f}"
            lines.append(
                f"| {c['case']} | {c['lighting']} | {what} | {r['spp']} | {r['psnr_db']:.2f} | "
                f"{r['psnr_corrected_db']:.2f} | {r['rel_mse']:.4f} | {r['fireflies']} | {r['gradient_ratio']:.2f} | "
                f"{eq} | {ratio} |"
            )
    lines += ["", "Summary (OIDN with albedo + normal guides):", ""]
    for s in res["summary"]:
        lines.append(f"- {s}")
    return "\n".join(lines) + "\n"


def summarise(cases: list[dict[str, Any]]) -> list[str]:
    out = []
    for c in cases:
        plain = {r["spp"]: r for r in c["rows"] if not r["denoise"] and r["guides"] is None}
        for r in c["rows"]:
            if r["denoise"] and r["guides"] == "albedo+normal":
                p = plain[r["spp"]]
                out.append(
                    f"{c['case']} ({c['lighting']}), {r['spp']} spp: PSNR {p['psnr_corrected_db']:.1f} -> "
                    f"{r['psnr_corrected_db']:.1f} dB, rel. MSE {p['rel_mse']:.4f} -> {r['rel_mse']:.4f}, "
                    f"fireflies {p['fireflies']} -> {r['fireflies']}, gradient ratio {p['gradient_ratio']:.2f} -> "
                    f"{r['gradient_ratio']:.2f}; as clean as {r['equivalent_spp']:.0f} plain spp"
                    f"{' (extrapolated)' if r['equivalent_extrapolated'] else ''}, time ratio {r['time_ratio']:.3f}"
                )
    return out


def main() -> None:
    import os

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--name", default=None)
    ap.add_argument("--quick", action="store_true", help="one photo and one panorama only")
    args = ap.parse_args()
    mitsuba()
    t0 = time.perf_counter()
    denoise_hdr(np.ones((8, 8, 3), np.float32))  # OIDN's device and weights, once per process
    init = time.perf_counter() - t0
    builders = [
        lambda: photo_case(7, 0),
        lambda: source_case(7, 0),
        lambda: photo_case(7, 1),
        lambda: source_case(7, 9),
    ]
    if args.quick:
        builders = builders[:2]
    cases = []
    for build in builders:
        case = build()
        print(f"[denoise] {case['name']} ({case['lighting']}) ...", flush=True)
        cases.append(run_case(case, args.ref_spp))
    res = {
        "machine": f"{platform.platform()}, {os.cpu_count()} CPUs",
        "variant": variant(),
        "threads": os.environ.get("DRJIT_NUM_THREADS", "all"),
        "ref_spp": args.ref_spp,
        "oidn_init_seconds": init,
        "cases": cases,
        "summary": summarise(cases),
    }
    stem = "denoise" + (f"-{args.name}" if args.name else "")
    (HERE / "results" / f"{stem}.json").write_text(json.dumps(res, indent=1))
    (HERE / "results" / f"{stem}.md").write_text(table(res))
    print("\n".join(res["summary"]))


if __name__ == "__main__":
    main()
