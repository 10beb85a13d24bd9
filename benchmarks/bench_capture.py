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

* **ingest with products** (``--only products``): the shipped mini card (21 captures, 1920x960 dual-fisheye,
  7 brackets) ingested with its products (merge, unwarp, tilt, EXR/PNG) with ``--jobs 1`` and ``--jobs 2``, and
  a card of Theta V-size captures (the mini card's scene02, 6 captures, upscaled to 5792x2896, EXIF kept) with
  ``--jobs 2``. Captures per minute, each run a fresh campaign, runs alternating between this tree and
  ``--baseline`` (another checkout's ``solidkit`` package: the "before"), the load average beside each.
* **merge against the OpenCV script** (``--only selfmerge``): ``solidkit capture merge`` of 3 JPEG frames with no
  curve given (the command as users run it: whole process) against a script doing ``cv2.imread``,
  ``cv2.createCalibrateDebevec`` + ``cv2.createMergeDebevec`` and the same EXR writer, on the same frames
  (the city panorama at 1920x960 and 5792x2896 through a gamma-2.2 camera), in alternating runs; error =
  median |log2| luminance error against the truth after the best global scale, pixels well exposed in a frame.

Writes benchmarks/results/capture.json and capture.md (a section run again replaces its numbers; the others
are kept). Run: ``.venv/bin/python benchmarks/bench_capture.py [--only merge,ingest,products,selfmerge]
[--baseline DIR] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import json
import os
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


def _env(tree: Path | None) -> dict:
    """The environment of a run of ``tree``'s solidkit (None: this checkout)."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    return env


def _timed(cmd: list[str], tree: Path | None, cwd: Path) -> tuple[float, float, float]:
    """(wall seconds, 1-minute load average before the run, CPU seconds of the run and its children) of one
    subprocess run. On a machine that other jobs keep busy the CPU seconds move far less than the wall time."""
    import resource

    load = os.getloadavg()[0]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, cwd=cwd, env=_env(tree))
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, load, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def _theta_v_card(folder: Path) -> Path:
    """The mini card's scene02 with every capture upscaled to 5792x2896 (Theta V dual-fisheye), EXIF kept."""
    from PIL import Image

    src = REPO / "solidkit" / "assets" / "campaign_mini" / "card" / "scene02"
    card = folder / "card_theta_v"
    for path in sorted(src.rglob("*")):
        dst = card / "scene02" / path.relative_to(src)
        if path.is_dir():
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix.upper() == ".JPG" and path.name.startswith("R"):
            with Image.open(path) as im:
                exif = im.info.get("exif", b"")
                im.convert("RGB").resize((5792, 2896), Image.BICUBIC).save(dst, exif=exif, quality=92)
        else:
            shutil.copyfile(path, dst)
    return card


def _median(xs: list[float]) -> float:
    return float(np.median(xs))


def bench_ingest_products(folder: Path, baseline: Path | None, repeats: int) -> dict:
    """Captures per minute of ``ingest`` with products, this tree and the baseline in turn (module docstring)."""
    mini = REPO / "solidkit" / "assets" / "campaign_mini" / "card"
    theta_v = _theta_v_card(folder)
    cards = {"mini": (mini, 21, (1, 2)), "theta_v": (theta_v, sum(1 for _ in theta_v.rglob("R*.JPG")), (2,))}
    trees = {"after": None, **({"before": baseline} if baseline is not None else {})}
    runs: dict[str, list] = {}
    k = 0
    for rep in range(repeats):
        for card_name, (card, n, jobs_list) in cards.items():
            for jobs in jobs_list:
                for label, tree in list(trees.items()) if rep % 2 == 0 else list(trees.items())[::-1]:
                    k += 1
                    camp = folder / f"camp{k}"
                    cmd = [str(REPO / ".venv" / "bin" / "solidkit"), "ingest", str(card), "-o", str(camp)]
                    wall, load, cpu = _timed([*cmd, "--jobs", str(jobs)], tree, folder)
                    shutil.rmtree(camp, ignore_errors=True)
                    runs.setdefault(f"{card_name}/jobs{jobs}/{label}", []).append(
                        {"wall_s": wall, "captures_per_min": 60 * n / wall, "load_1min": load, "cpu_s": cpu}
                    )
                    print(
                        card_name,
                        jobs,
                        label,
                        f"{wall:.1f} s",
                        f"{60 * n / wall:.0f}/min",
                        f"cpu {cpu:.1f} s",
                        f"load {load:.1f}",
                        flush=True,
                    )
    out: dict = {"captures": {name: c[1] for name, c in cards.items()}, "repeats": repeats, "runs": runs}
    out["median_captures_per_min"] = {key: _median([r["captures_per_min"] for r in v]) for key, v in runs.items()}
    out["median_cpu_s_per_capture"] = {
        key: _median([r["cpu_s"] for r in v]) / out["captures"][key.split("/")[0]] for key, v in runs.items()
    }
    return out


SELF_MERGE_PEER = r"""
import sys, time
import cv2, numpy as np
from solidkit.envmap.io import write_exr
paths, times, out = sys.argv[1:4], [float(t) for t in sys.argv[4:7]], sys.argv[7]
imgs = [cv2.imread(p) for p in paths]
t = np.asarray(times, np.float32)
curve = cv2.createCalibrateDebevec().process(imgs, t)
hdr = cv2.createMergeDebevec().process(imgs, t, curve)[..., ::-1]
write_exr(out, np.ascontiguousarray(hdr))
"""


def _log2_error(hdr: np.ndarray, truth: np.ndarray, well: np.ndarray) -> float:
    ok = well & (hdr.mean(-1) > 0)
    lr = np.log2(hdr[ok].mean(-1) / truth[ok].mean(-1))
    return float(np.median(np.abs(lr - np.median(lr))))


def bench_self_merge(folder: Path, baseline: Path | None, repeats: int) -> dict:
    """``capture merge`` (no curve given) against the OpenCV Debevec script, alternating (module docstring)."""
    import cv2

    from solidkit.envmap.io import read_exr

    out: dict = {}
    base, _ = read_exr(REPO / "solidkit" / "assets" / "hdr_panoramas" / "city.exr")
    for w, h in ((1920, 960), (5792, 2896)):
        sub = folder / f"self{w}"
        sub.mkdir()
        hdr = cv2.resize(base, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32)
        hdr *= 2.0 / np.median(hdr)
        rng = np.random.default_rng(0)
        paths, well = [], np.zeros((h, w), bool)
        for i, t in enumerate(TIMES):
            x = hdr * t * (1 + 0.01 * rng.standard_normal(hdr.shape, dtype=np.float32))
            z = np.round(255 * np.clip(x, 0, 1) ** (1 / 2.2)).astype(np.uint8)
            well |= ((z >= 10) & (z <= 245)).all(-1)
            p = sub / f"f{i}.jpg"
            cv2.imwrite(str(p), cv2.cvtColor(z, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
            paths.append(p)
        times = [repr(t) for t in TIMES]
        cmds = {
            "solidkit": (
                lambda o: [
                    str(REPO / ".venv" / "bin" / "solidkit"),
                    "capture",
                    "merge",
                    *map(str, paths),
                    "-o",
                    o,
                    "--times",
                    ",".join(times),
                ],
                None,
            ),
            "opencv_script": (lambda o: [sys.executable, "-c", SELF_MERGE_PEER, *map(str, paths), *times, o], None),
        }
        if baseline is not None:
            cmds["solidkit_before"] = (cmds["solidkit"][0], baseline)
        runs: dict[str, list] = {name: [] for name in cmds}
        errors: dict[str, float] = {}
        for rep in range(repeats):
            for name in list(cmds)[:: 1 if rep % 2 == 0 else -1]:
                make, tree = cmds[name]
                target = sub / f"{name}.exr"
                wall, load, cpu = _timed(make(str(target)), tree, REPO)
                runs[name].append({"wall_s": wall, "load_1min": load, "cpu_s": cpu})
                errors[name] = _log2_error(read_exr(target)[0], hdr, well)
                print(
                    w,
                    name,
                    f"{wall:.2f} s",
                    f"cpu {cpu:.2f} s",
                    f"error {errors[name]:.4f}",
                    f"load {load:.1f}",
                    flush=True,
                )
        med = {name: _median([r["wall_s"] for r in v]) for name, v in runs.items()}
        cpu_med = {name: _median([r["cpu_s"] for r in v]) for name, v in runs.items()}
        entry = {"runs": runs, "median_wall_s": med, "median_cpu_s": cpu_med, "log2_error": errors}
        entry["cpu_ratio_solidkit_over_opencv"] = cpu_med["solidkit"] / cpu_med["opencv_script"]
        entry["ratio_solidkit_over_opencv"] = med["solidkit"] / med["opencv_script"]
        if baseline is not None:
            entry["ratio_before_over_opencv"] = med["solidkit_before"] / med["opencv_script"]
            entry["cpu_ratio_before_over_opencv"] = cpu_med["solidkit_before"] / cpu_med["opencv_script"]
        out[f"{w}x{h}"] = entry
        shutil.rmtree(sub, ignore_errors=True)
    return out


def _markdown(result: dict) -> list[str]:
    lines = [
        "# Capture benchmarks",
        "",
        "Machine: " + result.get("machine", "?") + f", {result.get('cpus')} CPUs (shared with other jobs: compare the "
        "ratios of alternating runs, not the seconds; the load average is given beside each section).",
        "",
    ]
    if "merge_5792x2896_3_frames" in result:
        m = result["merge_5792x2896_3_frames"]
        lines += [
            "## HDR merge, 3 JPEG frames at 5792x2896 (decode + merge + EXR write), the curve given",
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
        ]
    if "self_merge" in result:
        sm = result["self_merge"]
        lines += [
            "## capture merge, 3 frames, no curve given, against the OpenCV Debevec script (alternating runs)",
            "",
            f"{sm.get('repeats', '?')} runs each; load average {sm.get('load', '?')}. Error: median |log2| against "
            "the truth after a global scale.",
            "",
            "| size | solidkit (s) | OpenCV script (s) | ratio | before (s) | ratio before | CPU ratio "
            "| CPU ratio before | error solidkit | error OpenCV | error before |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for size, e in sm["sizes"].items():
            med, err = e["median_wall_s"], e["log2_error"]
            lines.append(
                f"| {size} | {med['solidkit']:.2f} | {med['opencv_script']:.2f} | "
                f"{e['ratio_solidkit_over_opencv']:.2f} | "
                + (
                    f"{med['solidkit_before']:.2f} | {e['ratio_before_over_opencv']:.2f} | "
                    if "solidkit_before" in med
                    else "- | - | "
                )
                + f"{e.get('cpu_ratio_solidkit_over_opencv', float('nan')):.2f} | "
                f"{e.get('cpu_ratio_before_over_opencv', float('nan')):.2f} | "
                f"{err['solidkit']:.4f} | {err['opencv_script']:.4f} | "
                f"{err.get('solidkit_before', float('nan')):.4f} |"
            )
        lines.append("")
    if "ingest_products" in result:
        ip = result["ingest_products"]
        med = ip["median_captures_per_min"]
        lines += [
            "## Ingest with products (merge, unwarp, tilt, EXR/PNG), alternating runs",
            "",
            f"{ip['repeats']} runs each; 1-minute load average before each run in the JSON "
            f"(median {ip.get('median_load', '?')}).",
            "",
            "| card | jobs | captures | after (captures/min) | before (captures/min) | ratio | CPU-s per capture after "
            "| before |",
            "|---|---|---|---|---|---|---|---|",
        ]
        cpu = ip.get("median_cpu_s_per_capture", {})
        for key in sorted({k.rsplit("/", 1)[0] for k in med}):
            card, jobs = key.split("/")
            after, before = med.get(f"{key}/after"), med.get(f"{key}/before")
            lines.append(
                f"| {card} | {jobs.removeprefix('jobs')} | {ip['captures'][card]} | {after:.0f} | "
                + (f"{before:.0f} | {after / before:.2f} |" if before else "- | - |")
                + f" {cpu.get(f'{key}/after', float('nan')):.2f} | {cpu.get(f'{key}/before', float('nan')):.2f} |"
            )
        lines.append("")
    if "ingest_20_captures" in result:
        g = result["ingest_20_captures"]
        lines += [
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
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="merge,ingest,products,selfmerge", help="comma-separated sections")
    ap.add_argument("--baseline", type=Path, default=None, help="a source tree whose solidkit is the 'before'")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    only = set(args.only.split(","))
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "capture.json"
    result = json.loads(path.read_text()) if path.is_file() else {}
    result.update({"machine": platform.platform(), "cpus": os.cpu_count()})
    tmp = Path(tempfile.mkdtemp(prefix="bench_capture_"))
    try:
        if "merge" in only:
            result["merge_5792x2896_3_frames"] = bench_merge(tmp)
        if "ingest" in only:
            result["ingest_20_captures"] = bench_ingest(tmp)
        if "products" in only:
            result["ingest_products"] = bench_ingest_products(tmp, args.baseline, args.repeats)
            loads = [r["load_1min"] for v in result["ingest_products"]["runs"].values() for r in v]
            result["ingest_products"]["median_load"] = round(_median(loads), 1)
        if "selfmerge" in only:
            sizes = bench_self_merge(tmp, args.baseline, args.repeats)
            loads = [r["load_1min"] for e in sizes.values() for v in e["runs"].values() for r in v]
            result["self_merge"] = {"repeats": args.repeats, "load": round(_median(loads), 1), "sizes": sizes}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    lines = _markdown(result)
    (OUT / "capture.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
