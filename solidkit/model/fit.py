"""A minimal training loop for SOLID-Net and an analytic toy scene to exercise it.

:func:`fit` runs Adam on ``L_I + L_P`` (paper §4.3 and supplementary §1: Adam, lr 5e-4) over an
iterable of batches in the format of :mod:`solidkit.model.solidnet`. Real training (configuration
file, I-Net then P-Net, resumable, logged) is ``solidkit train`` (:mod:`solidkit.model.trainer`);
fine-tuning on real captures lives in :mod:`solidkit.finetune`. This loop serves the overfitting tests.

:func:`toy_batch` renders an analytic scene (a ground plane and a wall facing the camera, a sky with a
sun) with every ground-truth buffer consistent with the conventions: plane distances satisfy
``n . P + p = 0``, the image is ``(A ⊙ shading)^(1/2.2)``, shadows are 1 where lit.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import torch

from solidkit.envmap.coords import direction_from_angles, direction_grid, rotation_from_ypr
from solidkit.envmap.perspective import intrinsics_from_fov, pixel_rays
from solidkit.envmap.resample import sample_panorama
from solidkit.envmap.sun import detect_sun
from solidkit.model.config import SolidNetConfig, preset
from solidkit.model.losses import solidnet_losses
from solidkit.model.solidnet import SolidNet, save_checkpoint
from solidkit.model.sunhead import render_sun
from solidkit.synth.dataset import SynthDataset

__all__ = ["BATCH_KEYS", "toy_batch", "fit", "batch_to", "batch_from_synth"]


TOY_SUN_ENERGY = (2.2, 2.0, 1.7)
"""RGB energy of the toy sun (radiance x sr), about the horizontal irradiance of its sky."""


BATCH_KEYS = (
    "image",
    "K",
    "pitch",
    "roll",
    "pixels",
    "albedo",
    "normal",
    "distance",
    "shadow",
    "geometry_mask",
    "sky",
    "local",
    "sun_dir",
    "sun_visible",
)
"""The entries of a training batch (:mod:`solidkit.model.solidnet`), in the order they are collated."""


def _toy_sky(height: int, sun: torch.Tensor, ground: float = 0.3) -> torch.Tensor:
    """Radiance ``(height, 2 height, 3)`` of the toy sky: a blue gradient above the horizon, grey
    ground, and a sun of :data:`TOY_SUN_ENERGY` as a spherical Gaussian of 0.3° (one to two pixels
    at the model's resolution, like the generator's sun pixel)."""
    dirs = direction_grid(height, torch)
    up = -dirs[..., 1]
    sky = torch.stack([0.4 + 0.3 * up, 0.6 + 0.4 * up, 1.0 + 0.5 * up], dim=-1).clamp_min(0.0)
    disk = render_sun(sun[None].float(), torch.tensor([TOY_SUN_ENERGY]), torch.tensor([math.radians(0.3)]), height)
    out = sky + disk[0].permute(1, 2, 0)
    return torch.where(up[..., None] > 0, out, torch.full_like(out, ground))


def toy_batch(
    config: SolidNetConfig,
    batch: int = 1,
    n_probes: int = 2,
    seed: int = 0,
) -> dict[str, torch.Tensor]:
    """An analytic toy batch (see module docstring) at ``config.image_size`` / ``config.pano_height``.

    Each sample draws a sun direction, camera height, pitch, roll and wall distance from ``seed``.
    Returns the batch dictionary of :mod:`solidkit.model.solidnet` (float32, CPU).
    """
    g = torch.Generator().manual_seed(seed)
    H, W = config.image_size
    hp = config.pano_height
    K = torch.tensor(intrinsics_from_fov(math.radians(config.hfov_deg), W, H), dtype=torch.float32)
    rays = pixel_rays(K, W, H, torch, dtype=K.dtype)  # (H, W, 3), z = 1
    pano_dirs = direction_grid(hp, torch)
    out: dict[str, list[torch.Tensor]] = {k: [] for k in BATCH_KEYS}
    for _ in range(batch):
        r = torch.rand(6, generator=g)
        pitch, roll = math.radians(-8 + 10 * r[0].item()), math.radians(-4 + 8 * r[1].item())
        cam_h, wall_z = 1.5 + 0.1 * r[2].item(), 6.0 + 6.0 * r[3].item()
        sun = direction_from_angles(torch.tensor(-2.0 + 4.0 * r[4].item()), torch.tensor(0.3 + 0.7 * r[5].item()))
        R = rotation_from_ypr(*torch.tensor([0.0, pitch, roll], dtype=torch.float64)).to(
            torch.float32
        )  # camera -> panorama
        d = rays @ R.T  # ray directions (unnormalised) in the panorama frame
        # ground y = cam_h (normal up (0,-1,0)); wall z = wall_z (normal (0,0,-1)), up to 3 m above the camera
        t_ground = torch.where(
            d[..., 1] > 1e-6, cam_h / d[..., 1].clamp_min(1e-6), torch.full_like(d[..., 1], math.inf)
        )
        t_wall = torch.where(d[..., 2] > 1e-6, wall_z / d[..., 2].clamp_min(1e-6), torch.full_like(d[..., 2], math.inf))
        wall_ok = (t_wall * d[..., 1]) > -3.0
        t_wall = torch.where(wall_ok, t_wall, torch.full_like(t_wall, math.inf))
        on_wall = t_wall < t_ground
        t = torch.minimum(t_ground, t_wall)
        geo = torch.isfinite(t)
        n_pano = torch.where(on_wall[..., None], torch.tensor([0.0, 0.0, -1.0]), torch.tensor([0.0, -1.0, 0.0]))
        P = d * torch.where(geo, t, torch.zeros_like(t))[..., None]
        p = -(n_pano * P).sum(-1)  # plane distance: n . P + p = 0
        lit = (n_pano * sun).sum(-1).clamp_min(0.0)
        cast = (~on_wall) & (P[..., 0] > 0.0) & (P[..., 0] < 1.0)  # a 1 m wide cast-shadow band on the ground
        shadow = torch.where(geo & ~cast & (lit > 0), torch.ones_like(lit), torch.zeros_like(lit))
        albedo = torch.where(on_wall[..., None], torch.tensor([0.6, 0.45, 0.35]), torch.tensor([0.35, 0.35, 0.38]))
        shading = 1.5 * shadow[..., None] * lit[..., None] + 0.25
        sky_img = torch.from_numpy(sample_panorama(_toy_sky(hp, sun).numpy(), d.numpy()).astype("float32"))
        radiance = torch.where(geo[..., None], albedo * shading, sky_img)
        image = radiance.clamp(0, 1) ** (1 / 2.2)
        n_cam = n_pano @ R  # R^T n, row vectors
        pix = []
        for qx, qy in ((0.25, 0.8), (0.75, 0.8), (0.5, 0.9), (0.3, 0.7))[:n_probes]:
            pix.append([qx * (W - 1), qy * (H - 1)])
        sky = _toy_sky(hp, sun).permute(2, 0, 1)
        local = sky.clone()
        lower = pano_dirs[..., 1] > 0
        local[:, lower] = 0.35 * 0.8  # ground seen from the probe
        out["image"].append(image.permute(2, 0, 1))
        out["K"].append(K)
        out["pitch"].append(torch.tensor(pitch))
        out["roll"].append(torch.tensor(roll))
        out["pixels"].append(torch.tensor(pix))
        out["albedo"].append(torch.where(geo[..., None], albedo, torch.zeros_like(albedo)).permute(2, 0, 1))
        out["normal"].append(torch.where(geo[..., None], n_cam, torch.zeros_like(n_cam)).permute(2, 0, 1))
        out["distance"].append(torch.where(geo, p, torch.zeros_like(p))[None])
        out["shadow"].append(shadow[None])
        out["geometry_mask"].append(geo[None])
        out["sky"].append(sky)
        out["local"].append(local[None].expand(n_probes, -1, -1, -1))
        out["sun_dir"].append(sun.float())
        out["sun_visible"].append(torch.tensor(1.0))
    return {k: torch.stack(v).to(torch.bool if k == "geometry_mask" else torch.float32) for k, v in out.items()}


def batch_from_synth(items: list[dict[str, Any]]) -> dict[str, torch.Tensor]:
    """Collate :class:`solidkit.synth.dataset.SynthDataset` items into the model's batch format.

    Maps ``plane_distance -> distance``, ``global -> sky``, ``probes -> local``,
    ``probe_pixels -> pixels``; ``geometry_mask`` marks pixels with a normal (the generator writes
    0 on sky); ``sun_dir``/``sun_visible`` are what :func:`solidkit.envmap.detect_sun` finds in the
    global map (the truth of the sun terms). Probes the generator could not place (``probe_valid == 0``) are
    replaced by the sample's first valid one, so every sample keeps the same number of probes.
    """
    out: dict[str, list[torch.Tensor]] = {k: [] for k in BATCH_KEYS}
    for it in items:
        valid = it["probe_valid"] > 0
        if not valid.any():
            raise ValueError(f"synth sample {it.get('index')} has no valid probe")
        order = torch.where(valid, torch.arange(valid.numel()), torch.nonzero(valid)[0, 0])
        out["image"].append(it["image"])
        out["K"].append(it["K"])
        out["pitch"].append(it["pitch"])
        out["roll"].append(it["roll"])
        out["pixels"].append(it["probe_pixels"][order])
        out["albedo"].append(it["albedo"][:3])
        out["normal"].append(it["normal"][:3])
        out["distance"].append(it["plane_distance"][:1])
        out["shadow"].append(it["shadow"][:1])
        out["geometry_mask"].append(it["normal"][:3].norm(dim=0, keepdim=True) > 0.5)
        out["sky"].append(it["global"][:3])
        out["local"].append(it["probes"][order, :3])
        sun = detect_sun(it["global"][:3].permute(1, 2, 0).numpy())
        out["sun_dir"].append(torch.as_tensor(sun.direction if sun.found else [0.0, 0.0, 0.0], dtype=torch.float32))
        out["sun_visible"].append(torch.tensor(float(sun.found)))
    return {k: torch.stack(v).to(torch.bool if k == "geometry_mask" else torch.float32) for k, v in out.items()}


def batch_to(batch: dict[str, torch.Tensor], device: torch.device | str) -> dict[str, torch.Tensor]:
    """Move every tensor of a batch to ``device``."""
    return {k: v.to(device) for k, v in batch.items()}


def fit(
    model: SolidNet,
    batches: Iterable[dict[str, torch.Tensor]],
    steps: int,
    lr: float = 5e-4,
    teacher_geometry: bool = True,
    callback: Callable[[int, dict[str, float]], None] | None = None,
    max_seconds: float | None = None,
) -> list[dict[str, float]]:
    """Train ``model`` with Adam on ``L_I + L_P`` for ``steps`` batches (cycling ``batches``).

    ``teacher_geometry=True`` warps with the ground-truth normal/distance/shadow (P-Net sees clean
    warps while I-Net is still learning); ``False`` warps with I-Net's predictions, as at test time.
    Stops early after ``max_seconds``. Returns the per-step loss terms (floats).
    """
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    model.train()
    device = next(model.parameters()).device
    history: list[dict[str, float]] = []
    start = time.monotonic()
    it = _cycle(batches)
    for step in range(steps):
        batch = batch_to(next(it), device)
        geometry = {k: batch[k] for k in ("normal", "distance", "shadow") if k in batch} if teacher_geometry else None
        out = model(batch["image"], batch["K"], batch.get("pixels"), batch.get("pitch"), batch.get("roll"), geometry)
        losses = solidnet_losses(out, batch, model.config.loss_weights, model.config.loss_variant)
        opt.zero_grad(set_to_none=True)
        losses["total"].backward()
        opt.step()
        record = {k: float(v.detach()) for k, v in losses.items()}
        history.append(record)
        if callback is not None:
            callback(step, record)
        if max_seconds is not None and time.monotonic() - start > max_seconds:
            break
    model.eval()
    return history


def _cycle(batches: Iterable[Any]) -> Iterator[Any]:
    if isinstance(batches, dict):
        while True:
            yield batches
    while True:
        empty = True
        for b in batches:
            empty = False
            yield b
        if empty:
            raise ValueError("no batches to train on")


def train_on_synth(
    data: str,
    out: str,
    config: SolidNetConfig | None = None,
    *,
    steps: int = 100_000,
    max_seconds: float = 300.0,
    batch_size: int = 2,
    probes: int = 2,
    lr: float = 1e-3,
    seed: int = 0,
    threads: int = 1,
    half: bool = True,
    holdout: int = 0,
) -> dict[str, Any]:
    """Briefly train ``config`` (default ``small``) on a ``solidkit synth dataset`` folder and save a
    checkpoint with its card (data size, steps, time, hardware, seed, final losses).

    Each step draws ``batch_size`` samples and ``probes`` of their 4 probes at random (seeded); the
    last ``holdout`` samples of the dataset are not trained on (their indices go into the card).
    Returns the card.
    """
    import os
    import platform

    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    cfg = config or preset("small")
    ds = SynthDataset(data)
    if len(ds) == 0:
        raise ValueError(f"{data}: no kept samples")
    n_train = len(ds) - holdout
    if n_train < 1:
        raise ValueError(f"{data}: {len(ds)} samples leave none to train on with holdout={holdout}")
    items = [ds[i] for i in range(n_train)]  # a small dataset: keep it in memory
    held = [int(e["index"]) for e in ds.entries[n_train:]]
    g = torch.Generator().manual_seed(seed)

    def batches() -> Iterator[dict[str, torch.Tensor]]:
        while True:
            idx = torch.randperm(len(items), generator=g)[:batch_size].tolist()
            b = batch_from_synth([items[i] for i in idx])
            pick = torch.randperm(b["pixels"].shape[1], generator=g)[:probes]
            b["pixels"], b["local"] = b["pixels"][:, pick], b["local"][:, pick]
            yield b

    model = SolidNet(cfg)
    t0 = time.monotonic()
    history = fit(model, batches(), steps, lr=lr, max_seconds=max_seconds)
    seconds = time.monotonic() - t0
    last = history[-min(10, len(history)) :]
    card = {
        "what": "first small SOLID-Net checkpoint, trained briefly: a smoke-level model, not an accurate one",
        "config": cfg.name,
        "data": {
            "path": str(data),
            "samples": len(items),
            "held_out_indices": held,
            "generator": "solidkit synth dataset",
        },
        "steps": len(history),
        "batch_size": batch_size,
        "probes_per_sample": probes,
        "optimizer": f"Adam lr={lr}",
        "teacher_geometry": True,
        "seconds": round(seconds, 1),
        "hardware": (
            f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores (shared), "
            f"{threads} torch thread(s)"
        ),
        "torch": str(torch.__version__),
        "seed": seed,
        "loss_first": {k: round(v, 4) for k, v in history[0].items()},
        "loss_last10_mean": {k: round(sum(h[k] for h in last) / len(last), 4) for k in last[0]},
        "weights": "float16" if half else "float32",
    }
    save_checkpoint(model, out, card, half=half)
    return card
