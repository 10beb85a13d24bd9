"""Benchmark of the paper's diffuse convolution D(H, i) (solidkit.envmap.sh) at the paper's size.

Input: a batch of 256x128 HDR skies (sky gradient + a sharp sun of ~1e3 radiance), as the
SOLID-Net I-Net predicts them. D is evaluated at every pixel (the paper's N_ll). Methods:

* ``exact``: ``diffuse_convolution(pano)``: cached circulant operator, rfft along azimuth (exact);
* ``naive_full``: the paper's sum written directly at full resolution (the explicit-normals path,
  a (32768 x 32768) clamped-cosine kernel built chunk by chunk): the peer for time and accuracy;
* ``dense_src{h}``: the "precomputed dense (N_out x N_in) kernel + one matmul" design, with the
  source area-downsampled to height ``h`` (kernel build excluded from the time);
* ``sh_order2``: ``lambertian_sphere(sh_irradiance(sh_project(pano)))``, the SH approximation.

Writes benchmarks/results/sh.json and sh.md. Run: ``.venv/bin/python benchmarks/bench_sh.py``.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from solidkit.envmap import coords as C
from solidkit.envmap import sh
from solidkit.envmap.resample import resize

OUT = Path(__file__).resolve().parent / "results"
H, B = 128, 8


def skies(batch: int, height: int, seed: int = 0) -> np.ndarray:
    """(B, C, H, W) float64 HDR skies: gradient + ground + a 0.5-degree-ish sun of radiance ~1e3."""
    rng = np.random.default_rng(seed)
    d = C.direction_grid(height)
    out = []
    for _ in range(batch):
        az, el = rng.uniform(-np.pi, np.pi), rng.uniform(0.1, 1.2)
        sun = C.direction_from_angles(np.array(az), np.array(el))
        up = np.maximum(-d[..., 1], 0)
        sky = np.stack([0.3 + 0.5 * up, 0.4 + 0.6 * up, 0.6 + 0.9 * up], 0)
        sky = sky * (d[..., 1] < 0) + 0.2 * (d[..., 1] >= 0)
        sky = sky + 1e3 * np.exp(2e4 * (d @ sun - 1))[None]
        out.append(sky)
    return np.stack(out)


def timed(fn, repeat: int = 3) -> float:
    fn()
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def rel_errors(x: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    scale = np.abs(ref).max(axis=(-2, -1), keepdims=True)
    return {
        "max_abs_over_max": float((np.abs(x - ref) / scale).max()),
        "mean_rel": float((np.abs(x - ref) / np.abs(ref)).mean()),
    }


def main() -> None:
    torch.set_num_threads(2)
    pano64 = skies(B, H)
    pano = torch.from_numpy(pano64).float()
    grid = C.direction_grid(H)
    results: dict[str, dict] = {}

    # exact: float64 reference, then float32 timings (forward, forward + backward)
    t0 = time.perf_counter()
    exact = sh.diffuse_convolution(torch.from_numpy(pano64)).numpy()
    results["exact"] = {"first_call_s_incl_operator_build": time.perf_counter() - t0}
    results["exact"]["forward_s"] = timed(lambda: sh.diffuse_convolution(pano))
    x = pano.clone().requires_grad_()
    results["exact"]["forward_backward_s"] = timed(lambda: sh.diffuse_convolution(x).square().mean().backward())
    results["exact"].update(rel_errors(sh.diffuse_convolution(pano).double().numpy(), exact))

    # naive_full: the definition at full resolution (one panorama, float32, timed once)
    t0 = time.perf_counter()
    naive = sh.diffuse_convolution(pano[:1], torch.from_numpy(grid).float())
    t_naive = time.perf_counter() - t0
    results["naive_full"] = {"forward_s_per_panorama": t_naive, "forward_s": t_naive * B}
    results["naive_full"].update(rel_errors(naive.double().numpy(), exact[:1]))

    # dense kernel with a downsampled source
    n_out = torch.from_numpy(grid.reshape(-1, 3)).float()
    for hs in (16, 32, 64):
        d_in = torch.from_numpy(C.direction_grid(hs).reshape(-1, 3)).float()
        s_in = torch.from_numpy(C.solid_angle(hs).reshape(-1)).float()
        cos = n_out @ d_in.T
        kernel = (cos.clamp_min(0) * s_in / ((cos > 0).float() @ s_in)[:, None]).T.contiguous()  # (N_in, N_out)
        small = resize(pano, hs).reshape(B, 3, -1)

        def dense(small: torch.Tensor = small, kernel: torch.Tensor = kernel) -> torch.Tensor:
            return (small @ kernel).reshape(B, 3, H, 2 * H)

        t_resize = timed(lambda: resize(pano, hs))
        entry = {"kernel_MB": kernel.numel() * 4 / 2**20, "forward_s": timed(dense) + t_resize}
        entry.update(rel_errors(dense().double().numpy(), exact))
        results[f"dense_src{hs}"] = entry
        del kernel, cos, dense  # dense holds the kernel too: free it before the next, larger one is built

    # order-2 SH approximation of D
    approx = lambda: sh.lambertian_sphere(sh.sh_irradiance(sh.sh_project(pano)), H)  # noqa: E731
    results["sh_order2"] = {"forward_s": timed(approx)}
    results["sh_order2"].update(rel_errors(approx().double().numpy(), exact))

    for _name, r in results.items():
        r["time_ratio_vs_naive_full"] = r["forward_s"] / results["naive_full"]["forward_s"]
        r["time_ratio_vs_exact"] = r["forward_s"] / results["exact"]["forward_s"]

    meta = {
        "what": f"diffuse convolution D at every pixel of {B} x 3 x {H} x {2 * H} float32 skies (torch CPU)",
        "peer": "naive_full (the paper's sum at full resolution); errors vs exact (float64)",
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(),
    }
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "sh.json").write_text(json.dumps({"meta": meta, "results": results}, indent=2) + "\n")
    lines = [
        f"# diffuse convolution D: {meta['what']}",
        "",
        f"peer: {meta['peer']}; torch {meta['torch']}, {meta['threads']} threads",
        "",
        "| method | forward s | vs naive_full | vs exact | max abs err / max | mean rel err |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in results.items():
        lines.append(
            f"| {name} | {r['forward_s']:.4f} | {r['time_ratio_vs_naive_full']:.4f} | {r['time_ratio_vs_exact']:.2f} "
            f"| {r['max_abs_over_max']:.2e} | {r['mean_rel']:.2e} |"
        )
    lines += [
        "",
        f"exact forward+backward: {results['exact']['forward_backward_s']:.4f} s; "
        f"first call incl. operator build: {results['exact']['first_call_s_incl_operator_build']:.3f} s",
        "",
    ]
    (OUT / "sh.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
