"""Benchmark: dual-fisheye -> equirect unwarp at Theta V size, against ffmpeg's v360 filter.

Input: a 5792x2896 dual-fisheye JPEG (q95; the Theta V still size) rendered through the
``theta-v`` lens profile from a known panorama (the bundled city.exr, tonemapped), so the true
5376x2688 equirect is known. Output: 5376x2688 PNG, decode to encode, each method in its own
process (peak RSS of that process):

* ``solidkit (cold)``: ``solidkit capture unwarp`` logic (``unwarp_file``) with remap tables built;
* ``solidkit (disk cache)``: the same with the tables loaded from ``--cache-dir``;
* ``solidkit (memory cache)``: a second image in the same process (tables in the in-memory LRU);
  the time of that second call only;
* peer ``ffmpeg -vf v360=input=dfisheye:output=equirect`` (Debian's ffmpeg; equidistant model;
  its FOV picked as the best of a small scan by PSNR against the ground truth, its output yaw
  aligned by the best quarter turn: it centres the other lens). Wall time and peak RSS of the
  ffmpeg process itself.

Quality: PSNR (8-bit sRGB) against the ground-truth equirect, and the seam step at each tool's
lens cut (:func:`solidkit.capture.unwarp.seam_step`; solidkit feathers, so its step is measured on
its feathered output at the equal-margin cut). Writes benchmarks/results/unwarp.json and unwarp.md.
Run: ``.venv/bin/python benchmarks/bench_unwarp.py``.
"""

from __future__ import annotations

import json
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
IN_SIZE = (5792, 2896)
OUT_SIZE = (5376, 2688)

CHILD = r"""
import json, sys, time
from pathlib import Path
mode, src, dst, cache = sys.argv[1:5]
t0 = time.perf_counter()
from solidkit.capture.unwarp import unwarp_file
t_import = time.perf_counter() - t0
kw = dict(profile="theta-v", out_height=%d, cache_dir=cache if cache != "-" else None)
if mode == "memory":
    unwarp_file(src, dst, **kw)  # first call builds and caches the tables
    t0 = time.perf_counter()
s = unwarp_file(src, dst, **kw)
wall = time.perf_counter() - t0
print(json.dumps({"wall_s": wall, "import_s": t_import, "cache": s["cache"]}))
""" % OUT_SIZE[1]


def make_input(folder: Path) -> tuple[Path, np.ndarray]:
    import cv2

    from solidkit.camera.lens import load_profile
    from solidkit.capture.unwarp import render_fisheye
    from solidkit.envmap.coords import direction_grid
    from solidkit.envmap.io import read_exr, srgb_encode, tonemap
    from solidkit.envmap.resample import sample_panorama

    pano, _ = read_exr(REPO / "solidkit" / "assets" / "hdr_panoramas" / "city.exr")
    ldr = np.clip(tonemap(pano), 0, 1).astype(np.float32)
    linear = ldr ** 2.2  # treat the tonemapped image as sRGB-encoded content, linear for rendering
    fish = render_fisheye(linear, load_profile("theta-v"), IN_SIZE)
    src = folder / "dual_fisheye.jpg"
    enc = np.round(np.clip(srgb_encode(fish), 0, 1) * 255).astype(np.uint8)
    cv2.imwrite(str(src), cv2.cvtColor(enc, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    truth = sample_panorama(linear, direction_grid(OUT_SIZE[1]))
    truth8 = np.round(np.clip(srgb_encode(truth), 0, 1) * 255).astype(np.uint8)
    return src, truth8


def psnr8(a: np.ndarray, b: np.ndarray) -> float:
    err = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / err))


def run_child(mode: str, src: Path, dst: Path, cache: str) -> dict:
    """Our run in a fresh process, launched by a small wrapper that reports its peak RSS (Linux
    keeps ``ru_maxrss`` across exec, so a process forked from this big one would inherit ours)."""
    cmd = [sys.executable, "-c", CHILD, mode, str(src), str(dst), cache]
    proc = subprocess.run([sys.executable, "-c", FF_CHILD, *cmd], capture_output=True, text=True, cwd=REPO, check=True)
    lines = proc.stdout.strip().splitlines()
    r = json.loads(lines[-2])
    r["peak_rss_mib"] = json.loads(lines[-1])["peak_rss_mib"]
    return r


FF_CHILD = r"""
import json, resource, subprocess, sys, time
t0 = time.perf_counter()
out = subprocess.run(sys.argv[1:], check=True, capture_output=True, text=True).stdout
sys.stdout.write(out)
print(json.dumps({"wall_s": time.perf_counter() - t0,
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))
"""


def run_ffmpeg(src: Path, dst: Path, fov: float) -> dict:
    cmd = ["ffmpeg", "-y", "-loglevel", "error", "-i", str(src), "-vf",
           f"v360=input=dfisheye:output=equirect:ih_fov={fov}:iv_fov={fov}:w={OUT_SIZE[0]}:h={OUT_SIZE[1]}", str(dst)]
    proc = subprocess.run([sys.executable, "-c", FF_CHILD, *cmd], capture_output=True, text=True, check=True)
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    r["fov_deg"] = fov
    return r


def best_psnr(img: np.ndarray, truth8: np.ndarray) -> float:
    """PSNR after the best quarter-turn yaw (ffmpeg puts the other lens at the image centre)."""
    W = img.shape[1]
    return max(psnr8(np.roll(img, k * W // 4, axis=1), truth8) for k in range(4))


def main() -> int:
    import cv2

    from solidkit.camera.lens import load_profile
    from solidkit.capture.unwarp import cut_columns, get_maps, seam_step

    OUT.mkdir(exist_ok=True)
    results: dict = {"machine": f"{platform.platform()}, {__import__('os').cpu_count()} CPUs",
                     "input": f"{IN_SIZE[0]}x{IN_SIZE[1]} dual-fisheye JPEG q95 (theta-v, rendered from city.exr)",
                     "output": f"{OUT_SIZE[0]}x{OUT_SIZE[1]} PNG"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src, truth8 = make_input(tmp)
        rows = {}
        rows["solidkit (cold)"] = run_child("cold", src, tmp / "cold.png", "-")
        run_child("cold", src, tmp / "fill.png", str(tmp / "cache"))  # fill the disk cache
        rows["solidkit (disk cache)"] = run_child("disk", src, tmp / "disk.png", str(tmp / "cache"))
        rows["solidkit (memory cache)"] = run_child("memory", src, tmp / "mem.png", "-")
        ours = cv2.cvtColor(cv2.imread(str(tmp / "mem.png")), cv2.COLOR_BGR2RGB)
        rows["solidkit (memory cache)"]["psnr_db"] = psnr8(ours, truth8)
        maps, _ = get_maps(load_profile("theta-v"), IN_SIZE, OUT_SIZE[1], None, 0.0)
        rows["solidkit (memory cache)"]["seam_step"] = seam_step(cv2.cvtColor(ours, cv2.COLOR_RGB2GRAY), cut_columns(maps))["step"]
        del maps
        if shutil.which("ffmpeg"):
            best = None
            for fov in (200.0, 207.0, 214.0):
                r = run_ffmpeg(src, tmp / f"ff{fov:.0f}.png", fov)
                img = cv2.cvtColor(cv2.imread(str(tmp / f"ff{fov:.0f}.png")), cv2.COLOR_BGR2RGB)
                r["psnr_db"] = best_psnr(img, truth8)
                W, H = OUT_SIZE
                r["seam_step"] = seam_step(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), [[W // 4, 3 * W // 4]] * H)["step"]
                if best is None or r["psnr_db"] > best["psnr_db"]:
                    best = r
            rows["ffmpeg v360 (peer)"] = best
        results["rows"] = rows
        if "ffmpeg v360 (peer)" in rows:
            ff = rows["ffmpeg v360 (peer)"]["wall_s"]
            results["time_ratio_vs_ffmpeg"] = {k: v["wall_s"] / ff for k, v in rows.items() if k.startswith("solidkit")}
    (OUT / "unwarp.json").write_text(json.dumps(results, indent=1) + "\n")
    lines = ["# Unwarp benchmark", "", f"Machine: {results['machine']}.", "",
             f"Input {results['input']}; output {results['output']}; decode to encode, each method in its own process.", "",
             "| method | wall (s) | ratio vs ffmpeg | peak RSS (MiB) | PSNR vs truth (dB) | seam step (grey levels) |",
             "|---|---|---|---|---|---|"]
    for k, v in results["rows"].items():
        ratio = results.get("time_ratio_vs_ffmpeg", {}).get(k, 1.0 if "ffmpeg" in k else float("nan"))
        lines.append(f"| {k} | {v['wall_s']:.2f} | {ratio:.2f} | {v['peak_rss_mib']:.0f} | "
                     f"{v.get('psnr_db', float('nan')):.2f} | {v.get('seam_step', float('nan')):.2f} |")
    lines += ["", "solidkit's import time (not in wall): "
              + ", ".join(f"{k}: {v['import_s']:.1f} s" for k, v in results["rows"].items() if "import_s" in v),
              "ffmpeg's FOV: best PSNR of 200/207/214 deg (its equidistant model cannot match the Theta lens exactly)."]
    (OUT / "unwarp.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
