"""Benchmark of ``solidkit testset build`` and ``validate`` against plain file operations.

Input: the analytic campaign of ``tests/support/testset_campaign.py`` scaled to 8 scenes (3 captures each:
camera position + 2 probes; 640x480 photos, 512x256 aligned products). Peers, in the same run:

* build vs ``shutil.copytree`` of the files a test set holds (photos, aligned products, sun
  frames): what assembling costs beyond copying (resize/crop, sun-panorama rotation, hashing,
  schema);
* validate vs hashing every file of the test set (``sha256_file``): what the image and geometry
  checks (decoding, sky mask) cost beyond the checksum pass.

Writes benchmarks/results/testset.json and testset.md. Run: ``.venv/bin/python benchmarks/bench_testset.py``.
"""

from __future__ import annotations

import json
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from solidkit.fsutil import sha256_file  # noqa: E402
from solidkit.testset.build import build_testset  # noqa: E402
from solidkit.testset.validate import validate_testset  # noqa: E402
from tests.support.testset_campaign import SCENES, make_campaign  # noqa: E402

OUT = HERE / "results"
N_SCENES = 8


def best(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    base = SCENES["sA"]
    scenes = {f"s{k:02d}": (base[0] + 10 * k, base[1], base[2], base[3], base[4], base[5]) for k in range(N_SCENES)}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        camp = tmp / "camp"
        make_campaign(camp, scenes)
        counter = iter(range(100))

        def build():
            build_testset(camp, tmp / f"ts{next(counter)}")

        t_build = best(build)

        def copy():
            dst = tmp / f"copy{next(counter)}"
            shutil.copytree(camp / "align", dst / "align")
            shutil.copytree(camp / "originals", dst / "originals")
            for p in camp.glob("products/*/*/sun.png"):
                (dst / p.relative_to(camp)).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(p, dst / p.relative_to(camp))

        t_copy = best(copy)
        ts = tmp / "ts0"
        files = [p for p in ts.rglob("*") if p.is_file()]
        t_validate = best(lambda: validate_testset(ts))
        t_hash = best(lambda: [sha256_file(p) for p in files])
        mbytes = sum(p.stat().st_size for p in files) / 1e6
    res = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "scenes": N_SCENES,
        "captures_per_scene": 3,
        "build_s": round(t_build, 3),
        "copytree_peer_s": round(t_copy, 3),
        "build_over_copy": round(t_build / t_copy, 2),
        "validate_s": round(t_validate, 3),
        "sha256_peer_s": round(t_hash, 3),
        "validate_over_hash": round(t_validate / t_hash, 2),
        "files": len(files),
        "megabytes": round(mbytes, 1),
    }
    OUT.mkdir(exist_ok=True)
    (OUT / "testset.json").write_text(json.dumps(res, indent=1) + "\n")
    (OUT / "testset.md").write_text(
        "# testset build / validate\n\n"
        f"{N_SCENES} scenes x 3 captures, {len(files)} files ({mbytes:.1f} MB); best of 3; {res['machine']}\n\n"
        "| step | seconds | peer | peer seconds | ratio |\n|---|---|---|---|---|\n"
        f"| build | {t_build:.3f} | copytree of the inputs it copies | {t_copy:.3f} | {t_build / t_copy:.1f}x |\n"
        f"| validate | {t_validate:.3f} | sha256 of every file | {t_hash:.3f} | {t_validate / t_hash:.1f}x |\n"
    )
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
