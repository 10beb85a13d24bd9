"""Benchmark SOLID-Net forward passes: latency at 320x240, batch 1, on CPU with 2 threads (and 1),
parameter count and peak memory, for the ``small`` and ``paper`` configurations.

Peer measured in the same run: the ``LENet_reg`` direct-regression baseline of the same config
(one encoder + FC + panorama decoder), reported as latency ratios. Each configuration runs in a
fresh subprocess so that its peak resident memory (``ru_maxrss`` growth over the process before the
forward passes) is its own.

    .venv/bin/python benchmarks/bench_model.py [--repeats 5] [--configs small paper]

Writes benchmarks/results/model.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "model.json"


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _time(fn, repeats: int) -> dict[str, float]:
    fn()  # warm-up (allocator, oneDNN kernels)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return {"median_ms": 1e3 * statistics.median(times), "min_ms": 1e3 * min(times)}


def run_one(config: str, threads: int, repeats: int) -> dict:
    import torch

    from solidkit.envmap.perspective import intrinsics_from_fov
    from solidkit.model.baselines import LENetReg
    from solidkit.model.config import preset
    from solidkit.model.solidnet import SolidNet

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    cfg = preset(config)
    model = SolidNet(cfg).eval()
    peer = LENetReg(cfg).eval()
    image = torch.rand(1, 3, 240, 320)
    K = torch.tensor(intrinsics_from_fov(math.radians(cfg.hfov_deg), 320, 240), dtype=torch.float32)[None]
    pixels = torch.tensor([[[160.0, 200.0]]])
    rss0 = _rss_mb()
    with torch.inference_mode():
        inet = _time(lambda: model.inet(image), repeats)
        full = _time(lambda: model(image, K, pixels), repeats)
        rss_model = _rss_mb()
        lenet = _time(lambda: peer(image), repeats)
    return {
        "config": config,
        "threads": threads,
        "parameters": {
            "solidnet": sum(p.numel() for p in model.parameters()),
            "inet": sum(p.numel() for p in model.inet.parameters()),
            "pnet": sum(p.numel() for p in model.pnet.parameters()),
            "lenet_reg": sum(p.numel() for p in peer.parameters()),
        },
        "latency": {"inet": inet, "solidnet_1_probe": full, "lenet_reg": lenet},
        "ratio_vs_lenet_reg": {
            "inet": inet["median_ms"] / lenet["median_ms"],
            "solidnet_1_probe": full["median_ms"] / lenet["median_ms"],
        },
        "peak_rss_growth_mb_solidnet": rss_model - rss0,
        "peak_rss_mb": _rss_mb(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--configs", nargs="+", default=["small", "paper"])
    ap.add_argument("--threads", nargs="+", type=int, default=[2, 1])
    ap.add_argument("--child", nargs=2, metavar=("CONFIG", "THREADS"), help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(run_one(args.child[0], int(args.child[1]), args.repeats)))
        return
    runs = []
    for config in args.configs:
        for threads in args.threads:
            cmd = [sys.executable, __file__, "--child", config, str(threads), "--repeats", str(args.repeats)]
            res = subprocess.run(cmd, capture_output=True, text=True, check=True)
            run = json.loads(res.stdout.strip().splitlines()[-1])
            runs.append(run)
            lat = run["latency"]
            print(
                f"{config:6s} {threads} thr: I-Net {lat['inet']['median_ms']:8.1f} ms, SolidNet+1 probe "
                f"{lat['solidnet_1_probe']['median_ms']:8.1f} ms, LENet_reg {lat['lenet_reg']['median_ms']:8.1f} ms, "
                f"{run['parameters']['solidnet'] / 1e6:.2f} M params, peak RSS "
                f"+{run['peak_rss_growth_mb_solidnet']:.0f} MB"
            )
    import torch

    result = {
        "benchmark": "SOLID-Net forward, 320x240 input, batch 1, 128x256 panoramas, CPU",
        "peer": "LENet_reg baseline of the same config (direct sky regression), same process",
        "machine": {
            "cpu_count": os.cpu_count(),
            "load_average_at_end": os.getloadavg(),
            "platform": platform.platform(),
            "torch": torch.__version__,
            "note": "shared 2-core machine: other jobs ran concurrently; latencies are noisy upper bounds",
        },
        "gpu": "not measured: no GPU lent to this task",
        "repeats": args.repeats,
        "runs": runs,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    lines = [
        "# SOLID-Net forward pass (CPU, 320x240 input, batch 1)",
        "",
        f"Shared {os.cpu_count()}-core machine (load average {os.getloadavg()[0]:.1f} at the end); "
        "medians of the repeats; peer = LENet_reg of the same config, same process.",
        "",
        "| config | threads | params (M) | I-Net ms | SolidNet + 1 probe ms | LENet_reg ms | SolidNet / LENet_reg | "
        "peak RSS growth MB |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        lat = r["latency"]
        lines.append(
            f"| {r['config']} | {r['threads']} | {r['parameters']['solidnet'] / 1e6:.2f} | "
            f"{lat['inet']['median_ms']:.0f} | {lat['solidnet_1_probe']['median_ms']:.0f} | "
            f"{lat['lenet_reg']['median_ms']:.0f} | {r['ratio_vs_lenet_reg']['solidnet_1_probe']:.1f}x | "
            f"{r['peak_rss_growth_mb_solidnet']:.0f} |"
        )
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out} and {args.out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
