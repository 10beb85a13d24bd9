"""One SOLID-Img-style sample: HDR/LDR image, intrinsic buffers, global map and 4 local probes.

Buffers (all ``(H, W)`` or ``(H, W, 3)`` float32, 0 on sky pixels except ``shadow`` = 1; paper §3.1):

- ``albedo``: diffuse albedo (``BSDF.eval_diffuse_reflectance``), linear RGB;
- ``normal``: unit surface normal facing the camera, **camera frame** (x right, y down, z forward);
- ``depth``: z-depth along the optical axis, metres (``P = depth * v`` with ``v = ((x-cx)/fx, (y-cy)/fy, 1)``);
- ``plane_distance``: Im2Pano3D's distance of the pixel's tangent plane to the camera,
  ``p = -n . P = -depth (n . v)`` (>= 0 for camera-facing normals), so that the paper's
  reprojection ``P = -p / (v . n) v`` (§4.2) recovers the point;
- ``shadow``: ratio of the direct irradiance of a white Lambertian surface from the environment
  with and without shadow rays, from the same sample directions (paper: "render twice with
  shadows on and off"), in [0, 1]; 1 = unshadowed. Directions below the horizon are left out of
  both (the infinite ground hides them everywhere); see :mod:`solidkit.synth.plugins`.

Geometric buffers use one ray through each pixel centre (exact per pixel); the shadow
estimate uses ``buffer_spp`` emitter samples at that same point. The photo is path traced with
``spp`` samples jittered in each pixel (box filter). The global map is the environment alone
seen from the camera's panorama frame (``R_y(yaw)``); probes are 256x128 HDR panoramas in the
same frame, centred 10 cm along the normal off the surface point seen at one random pixel per
image quadrant (not sky, not within 5% of the border).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.envmap import CONVENTIONS_VERSION, angles_from_direction, direction_grid, tonemap, write_exr, write_ldr
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.envmap.sun import LUMINANCE_WEIGHTS
from solidkit.fsutil import atomic_write_text
from solidkit.synth.cameras import Camera, equirect_sensor, pinhole_sensor
from solidkit.synth.denoise import denoise_hdr, render_guides
from solidkit.synth.lighting import Lighting, random_lighting
from solidkit.synth.mitsuba_variant import mitsuba, variant
from solidkit.synth.render import render_buffers, render_rgb
from solidkit.synth.scene import CATEGORIES, CityBlock, city_block, to_mitsuba
from solidkit.synth.views import best_views

__all__ = [
    "SampleConfig",
    "render_rgb",
    "render_buffers",
    "render_panorama",
    "render_clean",
    "pick_probe_pixels",
    "Generator",
    "derive_seed",
    "FILES",
]

FILES: dict[str, Any] = {  # file names; "probes" lists one per probe
    "image": "image.exr",
    "ldr": "image.png",
    "albedo": "albedo.exr",
    "normal": "normal.exr",
    "depth": "depth.exr",
    "plane_distance": "plane_distance.exr",
    "shadow": "shadow.exr",
    "category": "category.png",
    "global": "global.exr",
    "probes": ["probe_0.exr", "probe_1.exr", "probe_2.exr", "probe_3.exr"],
    "meta": "sample.json",
}
VIEWS_PER_BLOCK = 6


@dataclass
class SampleConfig:
    """Renderer settings of a dataset (recorded in every sample JSON)."""

    width: int = 320
    height: int = 240
    hfov_deg: float = 60.0
    spp: int = 64
    max_depth: int = 6
    buffer_spp: int = 64
    env_height: int = 128
    env_spp: int = 64
    probe_height: int = 128
    probe_spp: int = 32
    probe_offset_m: float = 0.10
    firefly_k: float = 10.0
    border: float = 0.05
    candidates: int = 12
    min_categories: int = 3
    max_object_share: float = 0.35
    min_sky: float = 0.05
    item_size: tuple[int, int] = (64, 48)
    light_height: int = 512
    tex_size: int = 64
    p_sunsky: float = 0.5
    block_length: float = 60.0
    exclude_hdr: tuple[str, ...] = ()
    denoise: bool = False

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["item_size"] = list(self.item_size)
        if not self.denoise:  # recorded only when on, so records of plain renders stay as they were
            d.pop("denoise")
        if self.exclude_hdr:  # HDR maps held out (e.g. for a real test); absent when none, as in older datasets
            d["exclude_hdr"] = list(self.exclude_hdr)
        else:
            d.pop("exclude_hdr")
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SampleConfig:
        d = dict(d)
        d["item_size"] = tuple(d.get("item_size", (64, 48)))
        d["exclude_hdr"] = tuple(d.get("exclude_hdr", ()))
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


def derive_seed(*parts: int) -> int:
    """A 31-bit seed derived from integers (stable across runs and platforms; fits Mitsuba's samplers)."""
    return int(
        np.random.SeedSequence([int(p) & 0xFFFFFFFF for p in parts]).generate_state(1, np.uint32)[0] & 0x7FFFFFFF
    )


def render_panorama(
    scene: Any, position: np.ndarray, rotation: np.ndarray, height: int, spp: int, *, max_depth: int = 6, seed: int = 0
) -> np.ndarray:
    """HDR equirect ``(height, 2 height, 3)`` seen from ``position`` in the frame ``rotation`` (conventions §3)."""
    sensor = equirect_sensor(position, rotation, height, jitter=True, spp=spp, seed=seed)
    return render_rgb(scene, sensor, spp, max_depth=max_depth, seed=seed)


def render_clean(
    scene: Any,
    sensor: Any,
    spp: int,
    *,
    max_depth: int = 6,
    seed: int = 0,
    protect: np.ndarray | None = None,
    firefly_k: float = 10.0,
    wrap: bool = False,
    denoise: bool = False,
) -> tuple[np.ndarray, int]:
    """Path-traced linear RGB ``(H, W, 3)`` after the firefly treatment (:func:`suppress_fireflies`); returns
    (image, fireflies replaced).

    ``denoise``: then denoised by Open Image Denoise, guided by the albedo and normals of the same camera rays
    (:mod:`solidkit.synth.denoise`; ``protect`` pixels kept as rendered).
    """
    img = render_rgb(scene, sensor, spp, max_depth=max_depth, seed=seed)
    img, n = suppress_fireflies(img, protect, firefly_k, wrap=wrap)
    if not denoise:
        return img, n
    albedo, normal = render_guides(scene, sensor, spp, seed=seed)
    return denoise_hdr(img, albedo, normal, protect=protect), n


def suppress_fireflies(
    img: np.ndarray, protect: np.ndarray | None = None, k: float = 10.0, *, wrap: bool = False
) -> tuple[np.ndarray, int]:
    """Replace isolated path-tracing outliers ("fireflies") by their 3x3 median; returns (image, count).

    A pixel is an outlier when its luminance exceeds ``k`` times the median luminance of its
    3x3 neighbourhood and 4 times the image mean. ``protect`` (bool ``(H, W)``) marks pixels
    that may legitimately be isolated peaks (the directly seen sun). Plays the role of Cycles'
    "clamp indirect" (Blender's default 10), which the paper's renderer had and Mitsuba's path
    tracer lacks; rare near-specular caustics from the sun otherwise saturate even at 1/25000 s.
    ``wrap`` treats the columns as periodic (panoramas). ``k <= 0`` disables.
    """
    from scipy.ndimage import median_filter

    def median3(a: np.ndarray) -> np.ndarray:
        if not wrap:
            return median_filter(a, size=3, mode="nearest")
        padded = np.concatenate([a[:, -1:], a, a[:, :1]], axis=1)  # periodic columns, clamped rows
        return median_filter(padded, size=3, mode="nearest")[:, 1:-1]

    if k <= 0:
        return img, 0
    lum = img[..., :3] @ LUMINANCE_WEIGHTS
    med_l = median3(lum)
    bad = (lum > k * np.maximum(med_l, 1e-12)) & (lum > 4.0 * float(lum.mean()))
    if protect is not None:
        bad &= ~protect
    n = int(bad.sum())
    if n:
        img = img.copy()
        for c in range(img.shape[-1]):
            med_c = median3(img[..., c])
            img[..., c] = np.where(bad, med_c, img[..., c])
    return img, n


def sun_mask_panorama(
    sun: np.ndarray | None, rotation: np.ndarray, height: int, radius_deg: float = 3.0
) -> np.ndarray | None:
    """Pixels of a ``(height, 2 height)`` panorama in frame ``rotation`` within ``radius_deg`` of the sun."""
    if sun is None:
        return None

    d = rotation.T @ np.asarray(sun, float)
    return direction_grid(height) @ d > math.cos(math.radians(radius_deg))


def sun_mask_image(sun: np.ndarray | None, cam: Camera, radius_px: float = 4.0) -> np.ndarray | None:
    """Pixels of ``cam``'s image within ``radius_px`` of the projected sun (None when not in front)."""
    if sun is None:
        return None
    d = cam.rotation.T @ np.asarray(sun, float)
    if d[2] <= 0:
        return None
    u, v = (cam.K @ (d / d[2]))[:2]
    y, x = np.mgrid[0 : cam.height, 0 : cam.width]
    return (x - u) ** 2 + (y - v) ** 2 <= radius_px**2


def pick_probe_pixels(hit: np.ndarray, rng: np.random.Generator, border: float = 0.05) -> list[dict[str, Any]]:
    """One random valid pixel per image quadrant (TL, TR, BL, BR): a surface, not within ``border`` of the edge.

    A quadrant without a valid pixel borrows one from the whole valid area (``quadrant`` is then -1).
    Returns dicts with ``pixel`` ``[x, y]`` and ``quadrant``.
    """
    h, w = hit.shape
    bx, by = int(math.ceil(border * w)), int(math.ceil(border * h))
    valid = np.zeros_like(hit)
    valid[by : h - by, bx : w - bx] = hit[by : h - by, bx : w - bx]
    if not valid.any():
        return []
    out = []
    for q, (ys, xs) in enumerate(
        [
            (slice(0, h // 2), slice(0, w // 2)),
            (slice(0, h // 2), slice(w // 2, w)),
            (slice(h // 2, h), slice(0, w // 2)),
            (slice(h // 2, h), slice(w // 2, w)),
        ]
    ):
        mask = np.zeros_like(valid)
        mask[ys, xs] = valid[ys, xs]
        quadrant = q
        if not mask.any():
            mask, quadrant = valid, -1
        yy, xx = np.nonzero(mask)
        i = int(rng.integers(len(yy)))
        out.append({"pixel": [int(xx[i]), int(yy[i])], "quadrant": quadrant})
    return out


def _sun_json(sun: np.ndarray | None, cam: Camera) -> dict[str, Any]:
    if sun is None:
        return {"found": False}
    d = cam.pano_rotation.T @ sun
    az, el = angles_from_direction(d)
    return {
        "found": True,
        "direction_scene": [float(x) for x in sun],
        "direction_pano": [float(x) for x in d],
        "azimuth_deg": math.degrees(float(az)),
        "elevation_deg": math.degrees(float(el)),
    }


@dataclass
class Generator:
    """Renders samples ``index`` of a dataset with master ``seed`` (block ``index // 6``, sector ``index % 6``).

    The current block, its geometry-only scene and its selected views are cached, so consecutive
    indices (one shard) reuse them; each sector's view depends only on (seed, block, sector).
    """

    seed: int
    config: SampleConfig = field(default_factory=SampleConfig)
    _cache: dict[int, tuple[CityBlock, Any, dict[int, tuple[Camera, dict[str, Any]]]]] = field(
        default_factory=dict, repr=False
    )

    def block_and_view(self, block_id: int, sector: int) -> tuple[CityBlock, tuple[Camera, dict[str, Any]]]:
        """The block ``block_id`` and its best view in heading sector ``sector`` (cached per block)."""
        cfg = self.config
        if block_id not in self._cache:
            block = city_block(derive_seed(self.seed, block_id, 1), length=cfg.block_length)
            self._cache.clear()
            self._cache[block_id] = (block, to_mitsuba(block, None, tex_size=4), {})
        block, geometry, views = self._cache[block_id]
        if sector not in views:
            K = intrinsics_from_fov(math.radians(cfg.hfov_deg), cfg.width, cfg.height)
            rng = np.random.default_rng(derive_seed(self.seed, block_id, 2, sector))
            views[sector] = best_views(
                block,
                geometry,
                rng,
                K,
                cfg.width,
                cfg.height,
                candidates=cfg.candidates,
                min_categories=cfg.min_categories,
                max_object_share=cfg.max_object_share,
                min_sky=cfg.min_sky,
                item_size=cfg.item_size,
                sectors=(sector,),
            )[0]
        return block, views[sector]

    def lighting(self, index: int) -> Lighting:
        rng = np.random.default_rng(derive_seed(self.seed, index, 3))
        return random_lighting(
            rng, p_sunsky=self.config.p_sunsky, height=self.config.light_height, exclude=tuple(self.config.exclude_hdr)
        )

    def render(self, index: int, out_dir: str | Path, *, timings: dict[str, float] | None = None) -> dict[str, Any]:
        """Render sample ``index`` into ``out_dir`` (created); returns its JSON record.

        ``sample.json`` is written last, so a folder with it is complete (resumability).
        """
        import time

        mi = mitsuba()
        cfg = self.config
        out = Path(out_dir)
        tm = timings if timings is not None else {}
        t0 = time.perf_counter()
        block_id, sector = divmod(int(index), VIEWS_PER_BLOCK)
        block, (cam, view_stats) = self.block_and_view(block_id, sector)
        tm["views"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        light = self.lighting(index)
        emitter = light.emitter()
        scene = to_mitsuba(block, emitter, tex_size=cfg.tex_size)
        env_scene = to_mitsuba(None, light.emitter())
        tm["scene"] = time.perf_counter() - t0
        sseed = derive_seed(self.seed, index, 4)

        t0 = time.perf_counter()
        hdr, fireflies = render_clean(
            scene,
            pinhole_sensor(cam, spp=cfg.spp, seed=sseed),
            cfg.spp,
            max_depth=cfg.max_depth,
            seed=sseed,
            protect=sun_mask_image(light.sun, cam),
            firefly_k=cfg.firefly_k,
            denoise=cfg.denoise,
        )
        tm["image"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        buf = render_buffers(scene, cam, spp=cfg.buffer_spp, seed=sseed + 1)
        tm["buffers"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        glob = render_panorama(env_scene, np.zeros(3), cam.pano_rotation, cfg.env_height, cfg.env_spp, seed=sseed + 2)
        tm["global"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        rng = np.random.default_rng(derive_seed(self.seed, index, 5))
        probes = pick_probe_pixels(buf["hit"], rng, cfg.border)
        R = cam.rotation
        probe_imgs = []
        for k, p in enumerate(probes):
            x, y = p["pixel"]
            v = cam.rays()[y, x]
            d = R @ (v / np.linalg.norm(v))
            point = cam.position + float(buf["t"][y, x]) * d
            n = buf["normal_world"][y, x].astype(np.float64)
            centre = point + cfg.probe_offset_m * n
            p.update(
                point_scene=point.tolist(),
                normal_scene=n.tolist(),
                centre_scene=centre.tolist(),
                point_camera=((point - cam.position) @ R).tolist(),
                depth=float(buf["depth"][y, x]),
                category=CATEGORIES[block.category_of(np.array([buf["label"][y, x]]))[0]],
            )
            pseed = sseed + 10 + k
            img, n_ff = render_clean(
                scene,
                equirect_sensor(
                    centre, cam.pano_rotation, cfg.probe_height, jitter=True, spp=cfg.probe_spp, seed=pseed
                ),
                cfg.probe_spp,
                max_depth=cfg.max_depth,
                seed=pseed,
                protect=sun_mask_panorama(light.sun, cam.pano_rotation, cfg.probe_height),
                firefly_k=cfg.firefly_k,
                wrap=True,
                denoise=cfg.denoise,
            )
            fireflies += n_ff
            probe_imgs.append(img)
        tm["probes"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        prov = {"generator": "solidkit.synth", "index": int(index), "seed": int(self.seed)}
        write_exr(out / FILES["image"], hdr, prov)
        write_ldr(out / FILES["ldr"], np.asarray(tonemap(hdr)))
        write_exr(out / FILES["albedo"], buf["albedo"], prov)
        write_exr(out / FILES["normal"], buf["normal"], {**prov, "frame": "camera (x right, y down, z forward)"})
        write_exr(out / FILES["depth"], buf["depth"], {**prov, "units": "m", "kind": "z-depth"})
        write_exr(out / FILES["plane_distance"], buf["plane_distance"], {**prov, "units": "m"})
        write_exr(out / FILES["shadow"], buf["shadow"], prov)
        cats = block.category_of(buf["label"])
        write_ldr(out / FILES["category"], np.where(cats >= 0, cats + 1, 0).astype(np.uint8)[..., None].repeat(3, -1))
        write_exr(out / FILES["global"], glob, {**prov, "frame": "camera panorama frame"})
        for k, img in enumerate(probe_imgs):
            write_exr(out / FILES["probes"][k], img, {**prov, "frame": "camera panorama frame", "probe": k})
        record = {
            "index": int(index),
            "seed": int(self.seed),
            "sample_seed": int(sseed),
            "block_seed": int(block.seed),
            "block_id": block_id,
            "sector": sector,
            "conventions_version": CONVENTIONS_VERSION,
            "camera": cam.to_json(),
            "view_selection": view_stats,
            "lighting": light.meta,
            "sun": _sun_json(light.sun, cam),
            "probes": probes,
            "fireflies_suppressed": fireflies,
            "categories": list(CATEGORIES),
            "files": {k: v for k, v in FILES.items() if k != "meta"},
            "renderer": {"mitsuba": mi.__version__, "variant": variant(), **cfg.to_json()},
            "frames": {
                "scene": "x right, y down (gravity), z forward; ground y = 0; metres",
                "pano": "R_y(yaw) of the camera (conventions §2)",
                "normal": "camera frame",
            },
        }
        atomic_write_text(out / FILES["meta"], json.dumps(record, indent=1))
        tm["write"] = time.perf_counter() - t0
        return record
