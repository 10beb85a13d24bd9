"""Benchmark: ``solidkit capture unwarp`` as users run it (one file per call, a whole process) against ffmpeg's v360.

Input: a 5792x2896 dual-fisheye JPEG (q95; the Theta V still size) rendered through the
``theta-v`` lens profile from a known panorama (the bundled city.exr, tonemapped), the front lens
3 % brighter and the back lens 3 % darker than the scene (real units differ by a few percent: the
gain matching is part of the work), so the true 5376x2688 equirect is known. Output: 5376x2688
PNG, decode to encode. Every figure is a whole process, measured from outside with ``os.wait4``
(wall clock, user + system CPU and peak RSS of that process: what ``/usr/bin/time -v`` reports):

* ``solidkit CLI, cold``: ``solidkit capture unwarp SRC -o OUT --profile theta-v --size 5376x2688``
  with an empty table cache (``SOLIDKIT_CACHE_DIR`` a new folder each run): a user's first file
  of a camera and size (the tables are built, and written to the cache for the next run);
* ``solidkit CLI, warm``: the same command again (tables read from the per-user disk cache);
* ``solidkit in-process, 2nd image``: ``unwarp_file`` on a second image in one Python process
  (tables in memory), the time of that call only;
* peer ``ffmpeg -i SRC -vf v360=input=dfisheye:output=equirect:ih_fov=F:iv_fov=F:w=5376:h=2688 OUT``
  (Debian's ffmpeg; bilinear interpolation, v360's default ``interp=line``, as solidkit's; its
  equidistant model with the FOV ``F`` picked by PSNR against the ground truth from 200/207/214°).
  No gain matching, no blending (a hard cut at ±90° azimuth).

The three CLI-level commands run in turn (cold, warm, ffmpeg, cold, ...) ``--runs`` times after one
warm-up round; the tables quote medians (min-max), the ratio of the medians and the median of the
per-round ratios, with the load average before and after (the machine is shared). The CLI's
start-up (importing what ``solidkit capture unwarp`` needs) is timed alone too. Quality: PSNR
(8-bit sRGB) against the ground truth and the seam step at each tool's lens cut
(:func:`solidkit.capture.unwarp.seam_step`). ffmpeg absent: its rows are skipped with a message.
Writes benchmarks/results/unwarp.json and unwarp.md. Run: ``.venv/bin/python benchmarks/bench_unwarp.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
IN_SIZE = (5792, 2896)
OUT_SIZE = (5376, 2688)
LENS_GAIN = 1.03  # front lens x1.03, back lens /1.03
SOLIDKIT = [str(Path(sys.executable).with_name("solidkit"))]

IN_PROCESS = rf"""
import json, sys, time
from solidkit.capture.unwarp import unwarp_file
src, dst = sys.argv[1:3]
kw = dict(profile="theta-v", out_height={OUT_SIZE[1]:d}, cache_dir=None)
unwarp_file(src, dst, **kw)  # the first image builds the tables (in memory only)
t0 = time.perf_counter()
s = unwarp_file(src, dst, **kw)
print(json.dumps({{"wall_s": time.perf_counter() - t0, "cache": s["cache"]}}))
"""


def make_input(folder: Path) -> tuple[Path, np.ndarray]:
    import cv2

    from solidkit.camera.lens import load_profile
    from solidkit.capture.unwarp import render_fisheye
    from solidkit.envmap.coords import direction_grid
    from solidkit.envmap.io import read_exr, srgb_encode, tonemap
    from solidkit.envmap.resample import sample_panorama

    pano, _ = read_exr(REPO / "solidkit" / "assets" / "hdr_panoramas" / "city.exr")
    ldr = np.clip(tonemap(pano), 0, 1).astype(np.float32)
    linear = ldr**2.2  # treat the tonemapped image as sRGB-encoded content, linear for rendering
    fish = render_fisheye(linear, load_profile("theta-v"), IN_SIZE)
    fish[:, : IN_SIZE[0] // 2] *= LENS_GAIN  # the theta-v front lens is the left circle
    fish[:, IN_SIZE[0] // 2 :] /= LENS_GAIN
    src = folder / "dual_fisheye.jpg"
    enc = np.round(np.clip(srgb_encode(fish), 0, 1) * 255).astype(np.uint8)
    cv2.imwrite(str(src), cv2.cvtColor(enc, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    truth = sample_panorama(linear, direction_grid(OUT_SIZE[1]))
    truth8 = np.round(np.clip(srgb_encode(truth), 0, 1) * 255).astype(np.uint8)
    return src, truth8


def psnr8(a: np.ndarray, b: np.ndarray) -> float:
    err = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / err))


def best_psnr(img: np.ndarray, truth8: np.ndarray) -> float:
    """PSNR after the best quarter-turn yaw (ffmpeg puts the other lens at the image centre)."""
    W = img.shape[1]
    return max(psnr8(np.roll(img, k * W // 4, axis=1), truth8) for k in range(4))


RUSAGE_WRAPPER = r"""
import json, os, subprocess, sys, time
t0 = time.perf_counter()
proc = subprocess.Popen(sys.argv[1:], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
out, err = proc.stdout.read(), proc.stderr.read()
_, status, ru = os.wait4(proc.pid, 0)
wall = time.perf_counter() - t0
sys.stdout.write(out.decode(errors="replace"))
print(json.dumps({"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "peak_rss_mib": ru.ru_maxrss / 1024,
                  "code": os.waitstatus_to_exitcode(status), "stderr": err.decode(errors="replace")[-500:]}))
"""


def timed(cmd: list[str], env: dict | None = None) -> dict:
    """One whole process: wall clock, user + system CPU and peak RSS of that process from the kernel's
    accounting (``os.wait4``, as ``/usr/bin/time -v``), taken by a small wrapper process (Linux keeps a
    process's peak RSS across fork and exec: a child forked from this benchmark, which holds the images,
    would report ours)."""
    proc = subprocess.run(
        [sys.executable, "-c", RUSAGE_WRAPPER, *cmd], capture_output=True, text=True, env=env, cwd=REPO
    )
    lines = proc.stdout.rstrip().splitlines()
    r = json.loads(lines[-1])
    if proc.returncode != 0 or r["code"] != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r['code']}): {r['stderr']}{proc.stderr[-500:]}")
    return {**r, "stdout": "\n".join(lines[:-1])}


def summary(values: list[float]) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "runs": values}


def main() -> int:
    import cv2

    from solidkit.camera.lens import load_profile
    from solidkit.capture.unwarp import cut_columns, get_maps, seam_step

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="rounds of (cold, warm, ffmpeg), after one warm-up round")
    args = ap.parse_args()
    OUT.mkdir(exist_ok=True)
    has_ffmpeg = shutil.which("ffmpeg") is not None
    results: dict = {
        "machine": f"{platform.platform()}, {os.cpu_count()} CPUs",
        "input": f"{IN_SIZE[0]}x{IN_SIZE[1]} dual-fisheye JPEG q95 (theta-v, rendered from city.exr, "
        f"lens gains x{LENS_GAIN} / x1/{LENS_GAIN})",
        "output": f"{OUT_SIZE[0]}x{OUT_SIZE[1]} PNG",
        "runs": args.runs,
        "load_before": os.getloadavg(),
    }
    if not has_ffmpeg:
        print("ffmpeg not found: the peer rows are skipped (apt-get install ffmpeg to compare)", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src, truth8 = make_input(tmp)
        size = ["--size", f"{OUT_SIZE[0]}x{OUT_SIZE[1]}"]
        cli = [*SOLIDKIT, "capture", "unwarp", str(src), "--profile", "theta-v", *size]
        # as installed: bytecode compiled once (pip compiles wheels; an editable install writes it on first
        # use), so a PYTHONDONTWRITEBYTECODE in the calling shell must not make every run recompile
        base_env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(REPO / "solidkit")], check=True, env=base_env)
        warm_env = {**base_env, "SOLIDKIT_CACHE_DIR": str(tmp / "cache-warm")}
        ff_cmd = None
        if has_ffmpeg:  # v360's FOV by PSNR (untimed), then the timed command
            best = None
            for fov in (200.0, 207.0, 214.0):
                dst = tmp / f"ff{fov:.0f}.png"
                subprocess.run(
                    [
                        "ffmpeg",
                        "-y",
                        "-loglevel",
                        "error",
                        "-i",
                        str(src),
                        "-vf",
                        f"v360=input=dfisheye:output=equirect:ih_fov={fov}:iv_fov={fov}:w={OUT_SIZE[0]}:h={OUT_SIZE[1]}",
                        str(dst),
                    ],
                    check=True,
                )
                img = cv2.cvtColor(cv2.imread(str(dst)), cv2.COLOR_BGR2RGB)
                q = {
                    "fov_deg": fov,
                    "psnr_db": best_psnr(img, truth8),
                    "seam_step": seam_step(
                        cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), [[OUT_SIZE[0] // 4, 3 * OUT_SIZE[0] // 4]] * OUT_SIZE[1]
                    )["step"],
                }
                if best is None or q["psnr_db"] > best["psnr_db"]:
                    best = q
            results["ffmpeg_quality"] = best
            ff_cmd = [
                "ffmpeg",
                "-y",
                "-loglevel",
                "error",
                "-i",
                str(src),
                "-vf",
                f"v360=input=dfisheye:output=equirect:ih_fov={best['fov_deg']}:iv_fov={best['fov_deg']}"
                f":w={OUT_SIZE[0]}:h={OUT_SIZE[1]}",
                str(tmp / "ff.png"),
            ]
        rows: dict[str, list[dict]] = {"solidkit CLI, cold": [], "solidkit CLI, warm": [], "ffmpeg v360 (peer)": []}
        start = [sys.executable, "-c", "from solidkit.cli import build_app; build_app('capture')"]
        starts = []
        for r in range(args.runs + 1):
            cold_env = {**base_env, "SOLIDKIT_CACHE_DIR": str(tmp / f"cache-cold-{r}")}
            got = {
                "solidkit CLI, cold": timed([*cli, "-o", str(tmp / "cold.png")], cold_env),
                "solidkit CLI, warm": timed([*cli, "-o", str(tmp / "warm.png")], warm_env),
            }
            if ff_cmd:
                got["ffmpeg v360 (peer)"] = timed(ff_cmd)
            starts.append(timed(start, base_env)["wall_s"])
            shutil.rmtree(tmp / f"cache-cold-{r}", ignore_errors=True)
            if r:  # round 0 warms the page cache and fills the warm cache
                for k, v in got.items():
                    rows[k].append(v)
        inproc = timed([sys.executable, "-c", IN_PROCESS, str(src), str(tmp / "mem.png")])
        ours = cv2.cvtColor(cv2.imread(str(tmp / "warm.png")), cv2.COLOR_BGR2RGB)
        results["built_equals_cached"] = (tmp / "warm.png").read_bytes() == (tmp / "cold.png").read_bytes()
        maps, _ = get_maps(load_profile("theta-v"), IN_SIZE, OUT_SIZE[1], None, 0.0)
        results["solidkit_quality"] = {
            "psnr_db": psnr8(ours, truth8),
            "seam_step": seam_step(cv2.cvtColor(ours, cv2.COLOR_RGB2GRAY), cut_columns(maps))["step"],
        }
        del maps
        results["cli_start_s"] = summary(starts[1:])
        results["in_process_second_image_s"] = json.loads(inproc["stdout"].strip().splitlines()[-1])["wall_s"]
        results["rows"] = {
            k: {
                "wall_s": summary([v["wall_s"] for v in vs]),
                "cpu_s": summary([v["cpu_s"] for v in vs]),
                "peak_rss_mib": summary([v["peak_rss_mib"] for v in vs]),
            }
            for k, vs in rows.items()
            if vs
        }
        if rows["ffmpeg v360 (peer)"]:
            ff = rows["ffmpeg v360 (peer)"]
            results["ratios_vs_ffmpeg"] = {
                k: {
                    "wall_ratio_of_medians": results["rows"][k]["wall_s"]["median"]
                    / results["rows"]["ffmpeg v360 (peer)"]["wall_s"]["median"],
                    "wall_median_of_round_ratios": statistics.median(
                        a["wall_s"] / b["wall_s"] for a, b in zip(rows[k], ff)
                    ),
                    "peak_rss_ratio": results["rows"][k]["peak_rss_mib"]["median"]
                    / results["rows"]["ffmpeg v360 (peer)"]["peak_rss_mib"]["median"],
                }
                for k in rows
                if k.startswith("solidkit")
            }
    results["load_after"] = os.getloadavg()
    (OUT / "unwarp.json").write_text(json.dumps(results, indent=1) + "\n")
    lines = [
        "# Unwarp benchmark: the CLI as users run it, against ffmpeg's v360",
        "",
        f"Machine: {results['machine']}; load average (1, 5, 15 min) before "
        f"{tuple(round(x, 1) for x in results['load_before'])}, after "
        f"{tuple(round(x, 1) for x in results['load_after'])}: "
        + (
            "a quiet machine (ffmpeg's threads get both cores)"
            if max(results["load_before"][0], results["load_after"][0]) < 2.0
            else "a shared machine, busy with other jobs while this ran (wall times are inflated and noisy)"
        )
        + f"; the ratios come from {args.runs} alternating rounds, each command once per round, so each ratio "
        "compares runs under about the same load.",
        "",
        f"Input {results['input']}; output {results['output']}; each row a whole process, decode to encode; "
        "solidkit's bytecode compiled once beforehand, as an installed package has it.",
        "",
        "| command | wall (s): median (min-max) | wall vs ffmpeg (ratio of medians / median of round ratios) | CPU (s) "
        "| peak RSS (MiB) | RSS vs ffmpeg |",
        "|---|---|---|---|---|---|",
    ]
    for k, v in results["rows"].items():
        r = results.get("ratios_vs_ffmpeg", {}).get(k)
        ratio = (
            f"{r['wall_ratio_of_medians']:.2f} / {r['wall_median_of_round_ratios']:.2f}"
            if r
            else ("1" if "ffmpeg" in k else "-")
        )
        rss = f"{r['peak_rss_ratio']:.2f}" if r else ("1" if "ffmpeg" in k else "-")
        w = v["wall_s"]
        lines.append(
            f"| {k} | {w['median']:.2f} ({w['min']:.2f}-{w['max']:.2f}) | {ratio} | {v['cpu_s']['median']:.2f} | "
            f"{v['peak_rss_mib']['median']:.0f} | {rss} |"
        )
    ratios = results.get("ratios_vs_ffmpeg", {})
    if ratios:
        built, cached = ratios.get("solidkit CLI, cold"), ratios.get("solidkit CLI, warm")
        lines += [
            "",
            "Wall time against ffmpeg's v360 (median of the per-round ratios): tables built (a new camera, size or "
            f"levelling: with gravity metadata every capture) {built['wall_median_of_round_ratios']:.2f}x, tables "
            f"cached {cached['wall_median_of_round_ratios']:.2f}x (goal: 0.5x).",
        ]
    lines += [
        "",
        f"solidkit in-process, 2nd image (tables in memory; the call only): {results['in_process_second_image_s']:.2f} "
        "s.",
        f"CLI start-up (`build_app('capture')` in a fresh interpreter, the imports of `solidkit capture unwarp`): "
        f"median {results['cli_start_s']['median']:.2f} s.",
        "",
        "| quality | PSNR vs truth (dB) | seam step (grey levels) |",
        "|---|---|---|",
        f"| solidkit | {results['solidkit_quality']['psnr_db']:.2f} | {results['solidkit_quality']['seam_step']:.2f} |",
        f"| solidkit, tables built = cached output | {'byte-identical' if results['built_equals_cached'] else 'differ'}"
        " | |",
    ]
    if "ffmpeg_quality" in results:
        q = results["ffmpeg_quality"]
        lines.append(
            f"| ffmpeg v360 (FOV {q['fov_deg']:.0f}°, best of 200/207/214) | {q['psnr_db']:.2f} | {q['seam_step']:.2f} "
            "|"
        )
    else:
        lines.append("| ffmpeg v360 | not installed: skipped | |")
    (OUT / "unwarp.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
