"""Benchmark of solidkit.synth: seconds per sample and per buffer, and the effect of spp on noise.

Writes ``benchmarks/results/synth.json``. Measured in one run on this machine:

- a full sample at the default settings (320x240 photo at ``--spp`` 64, buffers with 32
  shadow samples, 256x128 global map at 64 spp, four 256x128 probes at 32 spp), its stages
  timed separately (view selection amortised over a block's six views is reported per view);
- noise versus spp: two renders of one view with different seeds; the per-pixel noise is
  ``rms(a - b) / sqrt(2)``, relative to the mean (HDR photo) or absolute (shadow map, in [0, 1]),
  and in 8-bit levels for the LDR photo; for the HDR photo also a robust estimate
  (``median |a - b| / (0.6745 sqrt 2)``), since rare bright paths (fireflies) dominate the rms;
- the peer: Mitsuba's ``scalar_rgb`` variant (the fallback) rendering the same 80x60 photo at
  16 spp in a subprocess, against the variant in use here: ratio = scalar seconds / ours.

Usage: ``python benchmarks/bench_synth.py [--samples N]`` (default 2).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PEER_SNIPPET = r"""
import os, sys, time, json
os.environ["SOLIDKIT_MITSUBA_VARIANT"] = sys.argv[1]
import numpy as np
from solidkit.synth.sample import Generator, SampleConfig, render_rgb
from solidkit.synth.cameras import pinhole_sensor
from solidkit.synth.scene import to_mitsuba
from solidkit.synth.mitsuba_variant import variant
g = Generator(1, SampleConfig(candidates=2))
block, (cam, _) = g.block_and_view(0, 0)
cam = cam.scaled(80, 60)
scene = to_mitsuba(block, g.lighting(0).emitter())
render_rgb(scene, pinhole_sensor(cam, spp=1), 1)  # warm-up (JIT compile)
t = time.perf_counter()
render_rgb(scene, pinhole_sensor(cam, spp=16, seed=3), 16, seed=3)
print(json.dumps({"variant": variant(), "seconds": time.perf_counter() - t}))
"""


def peer(variant: str) -> dict:
    out = subprocess.run([sys.executable, "-c", PEER_SNIPPET, variant], capture_output=True, text=True, cwd=HERE.parent)
    lines = [ln[ln.find("{") :] for ln in out.stdout.splitlines() if '{"variant"' in ln]  # after Mitsuba's colour codes
    if out.returncode or not lines:
        return {"variant": variant, "error": (out.stderr or out.stdout)[-500:]}
    return json.loads(lines[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=2)
    args = ap.parse_args()

    from solidkit.envmap import tonemap
    from solidkit.synth.cameras import pinhole_sensor
    from solidkit.synth.mitsuba_variant import mitsuba, variant
    from solidkit.synth.sample import Generator, SampleConfig, render_buffers, render_rgb
    from solidkit.synth.scene import to_mitsuba

    mi = mitsuba()
    used = variant()
    cfg = SampleConfig()
    gen = Generator(2026, cfg)
    per_sample = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.samples):
            tm: dict[str, float] = {}
            t0 = time.perf_counter()
            gen.render(i, Path(tmp) / f"{i}", timings=tm)
            tm["total"] = time.perf_counter() - t0
            per_sample.append(tm)
            print(f"sample {i}: {tm['total']:.1f} s", {k: round(v, 2) for k, v in tm.items()}, flush=True)

    # noise versus spp on sample 0's view and lighting
    block, (cam, _) = gen.block_and_view(0, 0)
    scene = to_mitsuba(block, gen.lighting(0).emitter())
    noise = []
    for spp in (4, 16, 64):
        t0 = time.perf_counter()
        a = render_rgb(scene, pinhole_sensor(cam, spp=spp, seed=1), spp, seed=1)
        dt = time.perf_counter() - t0
        b = render_rgb(scene, pinhole_sensor(cam, spp=spp, seed=2), spp, seed=2)
        mean = float(np.mean(0.5 * (a + b)))
        rel = float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(2) / mean)
        # robust: median |a - b| of a Gaussian is 0.6745 sqrt(2) sigma; fireflies dominate the rms
        rel_med = float(np.median(np.abs(a - b)) / (0.6745 * np.sqrt(2)) / mean)
        ldr = float(np.sqrt(np.mean((np.asarray(tonemap(a)) - np.asarray(tonemap(b))) ** 2)) / np.sqrt(2) * 255)
        noise.append(
            {
                "spp": spp,
                "seconds": dt,
                "hdr_rel_rms_noise": rel,
                "hdr_rel_robust_noise": rel_med,
                "ldr_rms_noise_8bit": ldr,
            }
        )
        print(noise[-1], flush=True)
    shadow_noise = []
    for spp in (4, 16, 64):
        t0 = time.perf_counter()
        a = render_buffers(scene, cam, spp=spp, seed=1)
        dt = time.perf_counter() - t0
        b = render_buffers(scene, cam, spp=spp, seed=2)
        hit = a["hit"]
        rms = float(np.sqrt(np.mean((a["shadow"][hit] - b["shadow"][hit]) ** 2)) / np.sqrt(2))
        shadow_noise.append({"buffer_spp": spp, "seconds": dt, "shadow_rms_noise": rms})
        print(shadow_noise[-1], flush=True)

    ours = peer(used)
    scalar = peer("scalar_rgb")
    keys = sorted({k for s in per_sample for k in s})
    mean = {k: float(np.mean([s.get(k, 0.0) for s in per_sample])) for k in keys}
    result = {
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "load_avg_1min": os.getloadavg()[0]},
        "mitsuba": mi.__version__,
        "variant": used,
        "config": cfg.to_json(),
        "seconds_per_sample": mean["total"],
        "seconds_per_stage_mean": mean,
        "per_sample": per_sample,
        "note": "stage 'views' (view selection) runs once per block sector; 'probes' = 4 probes; "
        "the machine is shared (see load_avg), so absolute times are upper bounds",
        "photo_noise_vs_spp": noise,
        "shadow_noise_vs_buffer_spp": shadow_noise,
        "peer_80x60_16spp": {
            "ours": ours,
            "scalar_rgb": scalar,
            "ratio_scalar_over_ours": (scalar.get("seconds", float("nan")) / ours["seconds"])
            if "seconds" in ours
            else None,
        },
    }
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "synth.json").write_text(json.dumps(result, indent=1))
    print(json.dumps({k: result[k] for k in ("variant", "seconds_per_sample", "peer_80x60_16spp")}, indent=1))


if __name__ == "__main__":
    main()
