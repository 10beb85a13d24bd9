"""Benchmark: rotating a 2048x1024 float32 RGB panorama (solidkit.envmap.resample.rotate).

Peers, all measured in the same run on the same image and rotation:

* ``solidkit_numpy``: ``rotate(pano, R)`` (cv2.remap, seam/pole padding); ``cold`` includes
  building the direction grid, ``warm`` reuses the cached grid (repeated rotations of one size);
* ``py360convert``: py360convert 1.0.4 has no rotation function, so the rotation is composed
  from its public utilities the way its ``e2p`` is: pixel grid -> ``coor2uv`` -> ``uv2unitxyz``
  -> rotate -> ``xyz2uv`` -> ``uv2coor`` -> ``EquirecSampler`` (1-pixel pole/seam padding,
  ``cv2.remap`` on 16-bit fixed-point maps, one channel at a time);
* ``naive_scipy``: per-pixel directions in NumPy + ``scipy.ndimage.map_coordinates`` (order 1,
  ``grid-wrap``: wraps the seam, but wraps the poles to the opposite pole);
* ``solidkit_torch_cpu``: ``rotate`` on a (4, 3, 128, 256) batch, forward and forward+backward,
  against the NumPy path looping over the same 4 panoramas;
* ``cube_round_trip``: equirect -> 6 faces of 512 -> equirect, solidkit vs py360convert's
  ``e2c``/``c2e`` (time and error against the original).

Accuracy: absolute error against the analytic rotated field (the test image is a smooth
function on the sphere), over the whole sphere, in the polar caps (|elevation| > 80°) and on
the output pixels whose source lies within one pixel of a pole (where interpolation crosses
the pole), relative to the image range.

Writes benchmarks/results/resample.json. Run: ``.venv/bin/python benchmarks/bench_resample.py``
(``pip install -e .[bench]`` for the py360convert peer; it is skipped when missing).
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy import ndimage

from solidkit.envmap import coords as C
from solidkit.envmap import resample

OUT = Path(__file__).resolve().parent / "results"
H = 1024
YPR_DEG = (30.0, 20.0, 10.0)
ROUNDS = 5


def field(d: np.ndarray) -> np.ndarray:
    """Smooth RGB test function on the sphere (no seam or pole artefacts)."""
    rng = np.random.default_rng(0)
    out = np.zeros((*d.shape[:-1], 3), np.float64)
    for c in range(3):
        for _ in range(4):
            a = rng.normal(size=3)
            out[..., c] += np.sin(rng.uniform(2.0, 6.0) * (d @ (a / np.linalg.norm(a))) + rng.uniform(0, 6.3))
    return out


def interleaved(fns: dict, rounds: int) -> dict[str, float]:
    """Best wall time of each callable, timed in alternation (fair under a fluctuating shared load)."""
    for fn in fns.values():
        fn()  # warm-up
    best = dict.fromkeys(fns, math.inf)
    for _ in range(rounds):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t)
    return best


def naive_scipy(pano: np.ndarray, R: np.ndarray) -> np.ndarray:
    h = pano.shape[0]
    x, y = C.coords_from_direction(C.direction_grid(h) @ R, h)
    return np.stack(
        [ndimage.map_coordinates(pano[..., c], [y - 0.5, x - 0.5], order=1, mode="grid-wrap") for c in range(3)], -1
    )


def py360convert_rotate(pano: np.ndarray, R: np.ndarray) -> np.ndarray:
    from py360convert import utils as U

    h, w = pano.shape[:2]
    flip = np.diag([1.0, -1.0, 1.0])  # py360convert's xyz has y up; ours y down
    Rp = (flip @ R @ flip).astype(np.float32)
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    uv = U.coor2uv(np.stack([xs, ys], -1), h, w)
    xyz = U.uv2unitxyz(uv) @ Rp  # row vectors: R^T d
    u, v = U.xyz2uv(xyz)
    cx, cy = U.uv2coor(u[..., 0], v[..., 0], h, w)
    sampler = U.EquirecSampler(cx, cy, order=1)
    return np.stack([sampler(pano[..., c]) for c in range(pano.shape[2])], -1)


def errors(out: np.ndarray, truth: np.ndarray, caps: np.ndarray, near_pole: np.ndarray, rng: float) -> dict:
    err = np.abs(out.astype(np.float64) - truth)
    return {
        "mean_abs_err_rel": float(err.mean() / rng),
        "max_abs_err_rel": float(err.max() / rng),
        "polar_caps_mean_abs_err_rel": float(err[caps].mean() / rng),
        "pole_crossing_max_abs_err_rel": float(err[near_pole].max() / rng),
    }


def main() -> dict:
    R = C.rotation_from_ypr(*np.radians(YPR_DEG))
    d = C.direction_grid(H)
    pano = field(d).astype(np.float32)
    truth = field(d @ R)
    rng = float(pano.max() - pano.min())
    caps = np.abs(C.angles_grid(H)[1]) > np.radians(80.0)
    src_y = C.coords_from_direction(d @ R, H)[1]
    near_pole = (src_y < 1.0) | (src_y > H - 1.0)  # output pixels sampled within a pixel of a pole
    res: dict = {
        "image": f"{2 * H}x{H} float32 RGB",
        "rotation_ypr_deg": YPR_DEG,
        "machine": {
            "python": platform.python_version(),
            "cpu_count": os.cpu_count(),
            "torch_threads": torch.get_num_threads(),
            "opencv": cv2.__version__,
            "numpy": np.__version__,
        },
        "timing": f"seconds, best of {ROUNDS} rounds timed in alternation after one warm-up call",
    }

    resample.cached_direction_grid.cache_clear()
    t0 = time.perf_counter()
    resample.rotate(pano, R)
    cold = time.perf_counter() - t0  # includes building the direction grid for this size
    methods = {
        "solidkit_numpy": lambda: resample.rotate(pano, R),
        "solidkit_numpy_cubic": lambda: resample.rotate(pano, R, "cubic"),
        "naive_scipy": lambda: naive_scipy(pano, R),
    }
    try:
        import py360convert  # noqa: F401

        methods["py360convert"] = lambda: py360convert_rotate(pano, R)
    except ImportError:
        res["py360convert"] = {"skipped": "not installed (pip install -e .[bench])"}
    times = interleaved(methods, ROUNDS)
    for name, fn in methods.items():
        res[name] = {"s": times[name], **errors(fn(), truth, caps, near_pole, rng)}
    res["solidkit_numpy"]["cold_s"] = cold
    ours = times["solidkit_numpy"]
    res["ratios_peer_time_over_solidkit"] = {
        "naive_scipy": times["naive_scipy"] / ours,
        "naive_scipy_vs_cold": times["naive_scipy"] / cold,
    }
    if "py360convert" in times:
        res["ratios_peer_time_over_solidkit"]["py360convert"] = times["py360convert"] / ours
        res["ratios_peer_time_over_solidkit"]["py360convert_vs_cold"] = times["py360convert"] / cold

    # torch on CPU, batch 4 x 3 x 128 x 256, against the NumPy path looping over the batch
    h_small, b = 128, 4
    ds = C.direction_grid(h_small)
    small = np.stack([field(ds @ C.rotation_from_ypr(0.3 * i, 0.1 * i)) for i in range(b)]).astype(np.float32)
    batch = torch.from_numpy(small).permute(0, 3, 1, 2).contiguous()
    Rb = torch.from_numpy(np.stack([C.rotation_from_ypr(0.2 * i, 0.1, -0.05 * i) for i in range(b)])).float()
    Rn = Rb.double().numpy()

    def fwd_bwd():
        x = batch.clone().requires_grad_()
        r = Rb.clone().requires_grad_()
        resample.rotate(x, r).square().mean().backward()

    tt = interleaved(
        {
            "forward": lambda: resample.rotate(batch, Rb),
            "forward_backward": fwd_bwd,
            "numpy_loop": lambda: [resample.rotate(small[i], Rn[i]) for i in range(b)],
        },
        3 * ROUNDS,
    )
    torch_out = resample.rotate(batch, Rb).permute(0, 2, 3, 1).numpy()
    np_out = np.stack([resample.rotate(small[i], Rn[i]) for i in range(b)])
    res["solidkit_torch_cpu"] = {
        "batch": f"{b} x 3 x {h_small} x {2 * h_small} float32",
        "forward_s": tt["forward"],
        "forward_backward_s": tt["forward_backward"],
        "numpy_loop_same_batch_s": tt["numpy_loop"],
        "ratio_torch_forward_over_numpy_loop": tt["forward"] / tt["numpy_loop"],
        "max_abs_diff_torch_vs_numpy_rel": float(np.abs(torch_out - np_out).max() / rng),
    }

    # equirect -> cube (512) -> equirect round trip at full size, against py360convert's e2c/c2e
    from solidkit.envmap.cubemap import cube_from_equirect, equirect_from_cube

    face = 512
    cube = {"solidkit": lambda: equirect_from_cube(cube_from_equirect(pano, face), H)}
    if "py360convert" in times:
        import py360convert

        cube["py360convert"] = lambda: py360convert.c2e(
            py360convert.e2c(pano, face, cube_format="dict"), H, 2 * H, cube_format="dict"
        )
    first = {}
    for name, fn in cube.items():  # first call: builds (and caches) the fixed maps of these sizes
        t0 = time.perf_counter()
        fn()
        first[name] = time.perf_counter() - t0
    ct = interleaved(cube, ROUNDS)
    everywhere = np.ones_like(caps)
    res["cube_round_trip"] = {
        "face": face,
        "timing": "first_call_s builds the size-dependent maps (both libraries cache them); s = warm",
        **{
            name: {"first_call_s": first[name], "s": ct[name], **errors(fn(), field(d), caps, everywhere, rng)}
            for name, fn in cube.items()
        },
    }
    if "py360convert" in ct:
        res["cube_round_trip"]["ratio_py360convert_over_solidkit_warm"] = ct["py360convert"] / ct["solidkit"]
    for name in cube:
        res["cube_round_trip"][name].pop("pole_crossing_max_abs_err_rel")

    OUT.mkdir(parents=True, exist_ok=True)
    from solidkit.fsutil import atomic_write_text

    atomic_write_text(OUT / "resample.json", json.dumps(res, indent=2) + "\n")
    return res


if __name__ == "__main__":
    print(json.dumps(main(), indent=2))
