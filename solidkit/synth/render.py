"""One Mitsuba render of a sensor: path-traced RGB (:func:`render_rgb`) and the intrinsic buffers
(:func:`render_buffers`).

The buffers' definitions (frames, units, the shadow ratio) are in :mod:`solidkit.synth.sample`;
the ``sk_buffers`` integrator that writes them is in :mod:`solidkit.synth.plugins`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from solidkit.synth.cameras import Camera, pinhole_sensor
from solidkit.synth.mitsuba_variant import mitsuba
from solidkit.synth.plugins import BUFFER_AOVS

__all__ = ["integrator", "render_rgb", "render_buffers"]


def integrator(kind: str, **props: Any) -> Any:
    mi = mitsuba()
    return mi.load_dict({"type": kind, **props})


def render_rgb(scene: Any, sensor: Any, spp: int, *, max_depth: int = 6, seed: int = 0) -> np.ndarray:
    """Path-traced linear RGB ``(H, W, 3)`` float32."""
    mi = mitsuba()
    img = mi.render(
        scene,
        sensor=sensor,
        integrator=integrator("path", max_depth=int(max_depth)),
        spp=int(spp),
        seed=int(seed) & 0x7FFFFFFF,
    )
    return np.array(img, dtype=np.float32)[..., :3]


def render_buffers(
    scene: Any, cam: Camera, *, spp: int = 16, shadows: bool = True, seed: int = 0
) -> dict[str, np.ndarray]:
    """Intrinsic buffers of ``cam`` (definitions: :mod:`solidkit.synth.sample`): raw AOVs plus derived camera-frame
    quantities.

    Returns ``t`` (ray distance), ``normal_world``, ``normal`` (camera frame), ``albedo``,
    ``label`` (object id, -1 = sky), ``depth``, ``plane_distance``, ``shadow`` and ``hit`` (bool).
    """
    mi = mitsuba()
    sensor = pinhole_sensor(cam, jitter=False, spp=spp, seed=seed)
    raw = np.array(
        mi.render(
            scene,
            sensor=sensor,
            integrator=integrator("sk_buffers", shadows=shadows),
            spp=int(spp),
            seed=int(seed) & 0x7FFFFFFF,
        ),
        dtype=np.float64,
    )
    aov = {name: raw[..., raw.shape[-1] - len(BUFFER_AOVS) + i] for i, name in enumerate(BUFFER_AOVS)}
    hit = aov["label"] > -0.5
    nw = np.stack([aov["nx"], aov["ny"], aov["nz"]], -1)
    nw /= np.maximum(np.linalg.norm(nw, axis=-1, keepdims=True), 1e-12)
    nw[~hit] = 0.0
    ncam = nw @ cam.rotation  # R^T n for row vectors
    v = cam.rays()
    depth = np.where(hit, aov["t"] / np.linalg.norm(v, axis=-1), 0.0)
    plane = np.where(hit, -depth * np.sum(ncam * v, axis=-1), 0.0)
    off = aov["shadow_off"]
    shadow = np.where(
        hit & (off > 0), np.clip(aov["shadow_on"] / np.maximum(off, 1e-20), 0.0, 1.0), np.where(hit, 0.0, 1.0)
    )
    albedo = np.stack([aov["albedo_r"], aov["albedo_g"], aov["albedo_b"]], -1)
    return {
        "t": aov["t"].astype(np.float32),
        "normal_world": nw.astype(np.float32),
        "normal": ncam.astype(np.float32),
        "albedo": albedo.astype(np.float32),
        "label": np.where(hit, np.round(aov["label"]), -1).astype(np.int32),
        "depth": depth.astype(np.float32),
        "plane_distance": plane.astype(np.float32),
        "shadow": shadow.astype(np.float32),
        "hit": hit,
    }
