"""Training throughput of SOLID-Net (samples/s) per configuration and per data path, on this CPU.

Model steps (Adam, batch 4, one torch thread, toy batches in the model's format so the data path is not
timed): I-Net on panorama crops (lighting decoders only), I-Net on full samples (all decoders), and
P-Net (I-Net frozen, 2 probes per image), for ``small`` (sun head, located losses) and its peer in the
same run, ``small-paper`` (the paper's sky decoder and losses at the same widths); for ``small-sun``
(``small`` with the low-resolution sun network, ``sun_net``, as docs/train_sun_v5.toml) also the ``sun`` stage's
step (the sun network alone on ``192 x 256`` crops).

Data paths: a crop of a real HDR panorama (:class:`solidkit.synth.panocrops.CropSampler`), a crop of a
rendered source (EXR read + crop; cached in memory after the first read), a sun-stage crop
(:class:`solidkit.model.suncrops.SunCropBank`, sources held in memory), and the rendering costs
recorded by the generators (``seconds`` of rendered sources, the dataset card's seconds per full
sample), whose ratio is the point of the crop path.

    .venv/bin/python benchmarks/bench_train.py [--repeats 4] [--sources DIR]

Writes benchmarks/results/train.json and train.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "hdr_panoramas"


def _rate(fn, n: int, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return n / statistics.median(times)


def model_steps(name: str) -> tuple[dict, float]:
    """The three training steps of configuration ``name`` as closures, and its parameter count (M)."""
    import torch

    from solidkit.model.config import preset
    from solidkit.model.fit import toy_batch
    from solidkit.model.losses import solidnet_losses
    from solidkit.model.solidnet import SolidNet
    from solidkit.model.warp import camera_rotation

    torch.manual_seed(0)
    cfg = preset(name)
    model = SolidNet(cfg)
    b = toy_batch(cfg, 4, 2, seed=0)
    crop = {k: b[k] for k in ("image", "K", "pitch", "roll", "sky", "sun_dir", "sun_visible")}
    full = {k: v for k, v in b.items() if k not in ("pixels", "local")}
    opt_i = torch.optim.Adam(model.inet.parameters(), 5e-4)
    opt_p = torch.optim.Adam(model.pnet.parameters(), 5e-4)

    def inet_step(batch, intrinsics):
        out = model.inet(batch["image"], intrinsics=intrinsics)
        out["rotation"] = camera_rotation(batch["pitch"], batch["roll"])
        loss = solidnet_losses(out, batch, cfg.loss_weights, cfg.loss_variant)["inet"]
        opt_i.zero_grad()
        loss.backward()
        opt_i.step()

    def pnet_step():
        for p in model.inet.parameters():
            p.requires_grad_(False)
        out = model(b["image"], b["K"], b["pixels"], b["pitch"], b["roll"])
        loss = solidnet_losses({k: out[k] for k in ("local_log", "local")}, b, cfg.loss_weights)["pnet"]
        opt_p.zero_grad()
        loss.backward()
        opt_p.step()
        for p in model.inet.parameters():
            p.requires_grad_(True)

    steps = {
        "inet_crops": lambda: inet_step(crop, False),
        "inet_full": lambda: inet_step(full, True),
        "pnet": pnet_step,
    }
    if cfg.sun_net:
        import math

        from solidkit.envmap.perspective import intrinsics_from_fov
        from solidkit.model.losses import sun_terms
        from solidkit.model.suncrops import CROP_SIZE

        h, w = CROP_SIZE
        K = torch.as_tensor(intrinsics_from_fov(math.radians(60.0), w, h), dtype=torch.float32).expand(4, 3, 3)
        sb = {
            "image": torch.rand(4, 3, h, w),
            "K": K,
            "pitch": b["pitch"],
            "roll": b["roll"],
            "sun_dir": b["sun_dir"],
            "sun_visible": b["sun_visible"],
            "sun_energy": torch.ones(4, 3),
            "sun_size": torch.full((4,), 0.005),
        }
        opt_s = torch.optim.Adam(model.inet.sun.parameters(), 1e-3)

        def sun_step():
            out = model.inet.sun(sb["image"], sb["K"], sb["pitch"], sb["roll"])
            loss = sum(sun_terms(out, sb["sun_dir"], sb["sun_visible"], sb["sun_energy"], sb["sun_size"]).values())
            opt_s.zero_grad()
            loss.backward()
            opt_s.step()

        steps["sun"] = sun_step
    return steps, sum(p.numel() for p in model.parameters()) / 1e6


def model_rates(names: list[str], repeats: int) -> dict[str, dict[str, float]]:
    """Samples/s (batch 4) of each step of each configuration, the configurations interleaved step by step
    (a shared machine's load then weighs on all of them alike)."""
    built = {n: model_steps(n) for n in names}
    times: dict[str, dict[str, list[float]]] = {n: {k: [] for k in built[n][0]} for n in names}
    for n in names:
        for fn in built[n][0].values():
            fn()  # warm-up
    for _ in range(repeats):
        for kind in ("inet_crops", "inet_full", "pnet", "sun"):
            for n in names:
                if kind not in built[n][0]:
                    continue
                t = time.perf_counter()
                built[n][0][kind]()
                times[n][kind].append(time.perf_counter() - t)
    return {
        n: {**{k: 4 / statistics.median(v) for k, v in times[n].items()}, "parameters_M": built[n][1]} for n in names
    }


def data_rates(sources: str | None, repeats: int) -> dict[str, float | None]:
    from solidkit.synth.panocrops import CropSampler, load_sources, real_source

    out: dict[str, float | None] = {}
    if REAL.is_dir():
        s = CropSampler([real_source(sorted(REAL.glob("*.exr"))[0])], seed=0)
        out["crop_real_per_s"] = _rate(lambda: [s(i) for i in range(4)], 4, repeats)
    if sources and Path(sources).is_dir():
        srcs = load_sources(sources)[:8]
        cold = CropSampler(srcs, seed=0)
        from solidkit.synth import panocrops

        panocrops._CACHE.clear()
        t = time.perf_counter()
        for i in range(len(srcs)):
            cold(i)
        out["crop_rendered_cold_per_s"] = len(srcs) / (time.perf_counter() - t)
        out["crop_rendered_cached_per_s"] = _rate(lambda: [cold(i) for i in range(len(srcs))], len(srcs), repeats)
        secs = [
            json.loads((p / "source.json").read_text())["seconds"]
            for p in sorted(Path(sources).glob("*/"))
            if (p / "source.json").is_file()
        ]
        out["render_source_seconds_median"] = statistics.median(secs) if secs else None
        from solidkit.model.suncrops import SunCropBank
        from solidkit.synth.panocrops import CropConfig

        bank = SunCropBank()
        t = time.perf_counter()
        bank.sync([s.name for s in srcs], srcs)
        out["sun_bank_add_per_s"] = len(srcs) / (time.perf_counter() - t)
        step = iter(range(10**6))
        out["sun_crop_per_s"] = _rate(lambda: bank.batch(0, next(step), 8, CropConfig(exposure_key=0.18)), 8, repeats)
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument(
        "--sources",
        default=None,
        help="rendered sources (solidkit synth sources); without it the rendered-crop and sun-bank rates are skipped",
    )
    ap.add_argument(
        "--full-sample-seconds",
        type=float,
        default=25.7,
        help="seconds per full synthetic sample (solidnet_small card: 25.7 s at 16 spp)",
    )
    a = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    res = {
        "machine": f"{platform.machine()}, {os.cpu_count()} shared cores, 1 torch thread, "
        f"load average {os.getloadavg()[0]:.1f} at start",
        "torch": torch.__version__,
        "models": model_rates(["small", "small-paper", "small-sun"], a.repeats),
        "data": data_rates(a.sources, a.repeats),
        "full_sample_seconds": a.full_sample_seconds,
    }
    res["load_average_end"] = round(os.getloadavg()[0], 1)
    m, d = res["models"], res["data"]
    lines = [
        "# SOLID-Net training throughput (CPU, samples/s, batch 4)",
        "",
        f"{res['machine']}; load average {res['load_average_end']} at the end. Peer in the same run: "
        "`small-paper` (the paper's sky decoder and losses, same widths).",
        "",
        "| config | params (M) | I-Net on crops | I-Net on full samples | P-Net (2 probes) | I-Net on crops vs "
        "small-paper | sun stage (sun network alone) | sun stage vs small-paper's I-Net on crops |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for n, r in m.items():
        sun = f"{r['sun']:.2f} | {r['sun'] / m['small-paper']['inet_crops']:.1f}x" if "sun" in r else "- | -"
        lines.append(
            f"| {n} | {r['parameters_M']:.2f} | {r['inet_crops']:.2f} | {r['inet_full']:.2f} | {r['pnet']:.2f} | "
            f"{r['inet_crops'] / m['small-paper']['inet_crops']:.2f}x | {sun} |"
        )
    lines += ["", "| data path | samples/s |", "|---|---|"]
    for k, v in d.items():
        if v is not None:
            lines.append(f"| {k} | {v:.2f} |")
    lines.append(f"| full synthetic sample (render) | {1 / a.full_sample_seconds:.3f} |")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "train.json").write_text(json.dumps(res, indent=1))
    (RESULTS / "train.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
