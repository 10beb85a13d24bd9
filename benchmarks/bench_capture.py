"""Benchmarks of the capture pipeline: HDR merge at Theta V size, and ingest throughput.

* **merge**: a 3-frame JPEG bracket (1/500, 1/60, 1/8 s) at 5792x2896 (Theta V dual-fisheye size),
  rendered from a known HDR (the bundled city panorama, upsampled, scaled so the sun clips) through
  a gamma-2.2 camera, 1 % noise, 8-bit, JPEG q95. ``solidkit`` = ``merge_files`` (decode, merge
  with ghost detection, EXR write); peer = OpenCV's ``cv2.createMergeDebevec`` with the *same*
  response curve, decode via ``cv2.imread`` and the same EXR writer. Reported: wall time, peak RSS
  (each method in its own process), median relative error vs the ground truth in pixels that are
  well exposed in some frame.
* **ingest**: a 20-capture card of 5376x2688 JPEGs (Theta S/V stitched size) in the camera layout;
  ``solidkit ingest --no-products`` with 1 and 2 jobs vs the peer ``cp`` + ``sha256sum`` of the
  same files (the least any checksummed copy must do). Reported: captures per minute.

Writes benchmarks/results/capture.json and capture.md. Run: ``.venv/bin/python benchmarks/bench_capture.py``.
"""

from __future__ import annotations

import json
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parents[1]
TIMES = [1 / 500, 1 / 60, 1 / 8]
W, H = 5792, 2896


def make_bracket(folder: Path) -> tuple[list[Path], Path]:
    import cv2

    from solidkit.envmap.io import read_exr

    hdr, _ = read_exr(REPO / "solidkit" / "assets" / "hdr_panoramas" / "city.exr")
    hdr = cv2.resize(hdr, (W, H), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    hdr *= 2.0 / np.median(hdr)
    np.save(folder / "truth.npy", hdr)
    rng = np.random.default_rng(0)
    paths = []
    for i, t in enumerate(TIMES):
        x = hdr * t * (1 + 0.01 * rng.standard_normal(hdr.shape, dtype=np.float32))
        z = np.round(255 * np.clip(x, 0, 1) ** (1 / 2.2)).astype(np.uint8)
        p = folder / f"f{i}.jpg"
        cv2.imwrite(str(p), cv2.cvtColor(z, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
        paths.append(p)
    return paths, folder / "truth.npy"


CHILD = r"""
import json, resource, sys, time
import numpy as np
method, folder = sys.argv[1], sys.argv[2]
from pathlib import Path
folder = Path(folder)
TIMES = [1 / 500, 1 / 60, 1 / 8]
paths = [folder / f"f{i}.jpg" for i in range(3)]
gamma = np.repeat(((np.arange(256) / 255.0) ** 2.2)[:, None], 3, axis=1)
t0 = time.perf_counter()
if method == "solidkit":
    from solidkit.capture.bracket_merge import merge_files
    stats = merge_files(paths, folder / "solidkit.exr", times=TIMES, response=gamma)[0]
    out = folder / "solidkit.exr"
else:
    import cv2
    from solidkit.envmap.io import write_exr
    imgs = [cv2.imread(str(p)) for p in paths]
    merge = cv2.createMergeDebevec()
    resp = gamma[:, None, ::-1].astype(np.float32).copy()  # OpenCV: (256, 1, 3), BGR
    hdr = merge.process(imgs, np.asarray(TIMES, np.float32), resp)[..., ::-1]
    write_exr(folder / "opencv.exr", np.ascontiguousarray(hdr))
    out = folder / "opencv.exr"
    stats = {}
wall = time.perf_counter() - t0
print(json.dumps({"wall_s": wall, "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "out": str(out), "ghost_fraction": stats.get("ghost_fraction")}))
"""


def bench_merge(folder: Path) -> dict:
    import cv2

    from solidkit.envmap.io import read_exr

    paths, truth_path = make_bracket(folder)
    truth = np.load(truth_path)
    good = np.zeros(truth.shape[:2], bool)
    for t in TIMES:
        c = np.clip(truth * t, 0, 1) ** (1 / 2.2)
        good |= ((c > 0.1) & (c < 0.9)).all(-1)
    res = {}
    for method in ("solidkit", "opencv_debevec"):
        r = subprocess.run(
            [sys.executable, "-c", CHILD, method, str(folder)], capture_output=True, text=True, cwd=REPO, check=True
        )
        info = json.loads(r.stdout.strip().splitlines()[-1])
        hdr, _ = read_exr(info["out"])
        rel = np.abs(hdr - truth) / truth
        info["median_rel_error_well_exposed"] = float(np.median(rel[good]))
        info["well_exposed_fraction"] = float(good.mean())
        res[method] = info
    del cv2
    res["time_ratio_solidkit_over_opencv"] = res["solidkit"]["wall_s"] / res["opencv_debevec"]["wall_s"]
    return res


def bench_ingest(folder: Path, n: int = 20) -> dict:
    from PIL import Image, TiffImagePlugin

    card = folder / "card" / "DCIM" / "100RICOH"
    card.mkdir(parents=True)
    rng = np.random.default_rng(1)
    base = (rng.random((2688 // 8, 5376 // 8, 3)) * 255).astype(np.uint8)
    big = np.asarray(Image.fromarray(base).resize((5376, 2688), Image.BICUBIC))
    for i in range(n):
        ex = Image.Exif()
        ex[0x010F], ex[0x0110] = "RICOH", "RICOH THETA V"
        ifd = ex.get_ifd(0x8769)
        ifd[0x829A] = TiffImagePlugin.IFDRational(1, 100 * (1 + i % 3))
        ifd[0x9003] = f"2024:06:01 12:{i // 6:02d}:{(i * 7) % 60:02d}"
        Image.fromarray(np.roll(big, i * 16, axis=1)).save(
            card / f"R00100{i + 1:02d}.JPG", exif=ex.tobytes(), quality=92
        )
    size_mb = sum(p.stat().st_size for p in card.iterdir()) / 2**20
    res: dict = {"captures": n, "card_mib": size_mb}
    dst = folder / "cp"
    t0 = time.perf_counter()
    dst.mkdir()
    subprocess.run(["cp", "-r", str(card), str(dst)], check=True)
    subprocess.run(["sha256sum", *map(str, sorted((dst / "100RICOH").iterdir()))], check=True, capture_output=True)
    subprocess.run(["sync"], check=True)
    res["peer_cp_sha256sum_s"] = time.perf_counter() - t0
    for jobs in (1, 2):
        camp = folder / f"camp{jobs}"
        t0 = time.perf_counter()
        subprocess.run(
            [
                str(REPO / ".venv" / "bin" / "solidkit"),
                "ingest",
                str(folder / "card"),
                "-o",
                str(camp),
                "--no-products",
                "--jobs",
                str(jobs),
            ],
            check=True,
            capture_output=True,
            cwd=REPO,
        )
        res[f"solidkit_jobs{jobs}_s"] = time.perf_counter() - t0
        res[f"solidkit_jobs{jobs}_captures_per_min"] = 60 * n / res[f"solidkit_jobs{jobs}_s"]
        res[f"time_ratio_jobs{jobs}_over_peer"] = res[f"solidkit_jobs{jobs}_s"] / res["peer_cp_sha256sum_s"]
    res["peer_captures_per_min"] = 60 * n / res["peer_cp_sha256sum_s"]
    return res


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="bench_capture_"))
    try:
        result = {
            "machine": platform.platform(),
            "cpus": __import__("os").cpu_count(),
            "load_average_at_start": list(__import__("os").getloadavg()),
            "merge_5792x2896_3_frames": bench_merge(tmp),
            "ingest_20_captures": bench_ingest(tmp),
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    (OUT / "capture.json").write_text(json.dumps(result, indent=2) + "\n")
    m, g = result["merge_5792x2896_3_frames"], result["ingest_20_captures"]
    lines = [
        "# Capture benchmarks",
        "",
        f"Machine: {result['machine']}, {result['cpus']} CPUs, load average at start "
        f"{result['load_average_at_start'][0]:.1f} (shared machine: compare the ratios, not the seconds).",
        "",
        "## HDR merge, 3 JPEG frames at 5792x2896 (decode + merge + EXR write)",
        "",
        "| method | wall (s) | peak RSS (MiB) | median rel. error (well exposed) |",
        "|---|---|---|---|",
        *[
            f"| {k} | {m[k]['wall_s']:.2f} | {m[k]['peak_rss_mib']:.0f} | "
            f"{100 * m[k]['median_rel_error_well_exposed']:.2f} % |"
            for k in ("solidkit", "opencv_debevec")
        ],
        "",
        f"Time ratio solidkit / OpenCV: {m['time_ratio_solidkit_over_opencv']:.2f} "
        "(solidkit also computes the ghost mask and saturation/black masks).",
        "",
        f"## Ingest, {g['captures']} captures of 5376x2688 ({g['card_mib']:.0f} MiB), no products",
        "",
        "| method | wall (s) | captures / min |",
        "|---|---|---|",
        f"| cp + sha256sum (peer) | {g['peer_cp_sha256sum_s']:.2f} | {g['peer_captures_per_min']:.0f} |",
        f"| solidkit ingest --jobs 1 | {g['solidkit_jobs1_s']:.2f} | {g['solidkit_jobs1_captures_per_min']:.0f} |",
        f"| solidkit ingest --jobs 2 | {g['solidkit_jobs2_s']:.2f} | {g['solidkit_jobs2_captures_per_min']:.0f} |",
        "",
        "solidkit also fully decodes every JPEG (truncation check), reads EXIF/XMP/maker notes, hashes the source "
        "and the bytes it writes, and fsyncs each original.",
    ]
    (OUT / "capture.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
