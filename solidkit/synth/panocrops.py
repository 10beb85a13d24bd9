"""The cheap sample path of the global branch: limited-FOV crops of HDR panoramas.

Hold-Geoffroy et al. (CVPR 2017, "Deep Outdoor Illumination Estimation") train their sky
regressor on many perspective crops of each outdoor panorama; here the same idea feeds I-Net's
lighting branch (the global sky ``H_g`` and its sun). A *source* is one HDR panorama of a scene
together with the lighting that lit it, both in the scene frame (docs/conventions.md; x right,
y down, z forward):

- ``render_source``: a city block of :mod:`solidkit.synth.scene` rendered by Mitsuba as one
  equirect panorama at a random walkable position 1.5-1.6 m above the floor (low spp: the crops
  are tonemapped to 8 bits and area-resized, where path-tracing noise hardly matters), lit by a
  random :func:`solidkit.synth.lighting.random_lighting` (Mitsuba's sun-sky with sampled
  turbidity and sun position, or a real HDR map turned about the vertical). The global target is
  the lighting itself, area-downsampled (energy preserving) to the probe height.
- ``real_source``: a real HDR panorama (e.g. ``../shared/data/real/hdr_panoramas``) is both the
  scene and the global target (its own ground included), exactly as Hold-Geoffroy et al. crop
  SUN360.

A crop (:class:`CropSampler`) draws a camera ``R = rotation_from_ypr(yaw, pitch, roll)``, a
horizontal FOV, an exposure and a white balance (applied to the scene *and* the target: a brighter
scene is a brighter sky, so the HDR scale stays tied to the image) and a horizontal flip (the
target is mirrored in azimuth, the roll negated). With ``CropConfig.exposure_key`` the exposure is
metered first, as a camera's auto-exposure does (:func:`metered_gain`: the view's log-average
luminance brought to the key, Reinhard et al. 2002), then jittered; without it the gain is 1 (the
crops of checkpoints v1-v4: rendered street canyons came out 2.5-5 stops darker than the real panoramas, whose
log-average is ~0.18, so their shadows and facades were near black). The image is the paper's tonemap of the
perspective view (:func:`solidkit.envmap.perspective_crop`); the target is the lighting seen from
the camera's panorama frame ``R_y(yaw)`` (conventions §2). Each crop is a pure function of
``(seed, index)``, so an epoch is reproducible and resumable.
"""

from __future__ import annotations

import functools
import json
import math
import os
from collections import OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.envmap import (
    detect_sun,
    downsample,
    perspective_crop,
    read_exr,
    rotate,
    rotation_from_ypr,
    rotation_y,
    tonemap,
    write_exr,
)
from solidkit.envmap.coords import direction_from_angles
from solidkit.envmap.io import read_panorama
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.envmap.sun import luminance
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_text
from solidkit.synth.cameras import equirect_sensor, sample_candidate
from solidkit.synth.lighting import HDR_DIR, random_lighting
from solidkit.synth.mitsuba_variant import mitsuba, variant
from solidkit.synth.sample import derive_seed, render_clean, sun_mask_panorama
from solidkit.synth.scene import city_block, to_mitsuba

__all__ = [
    "metered_gain",
    "SourceConfig",
    "render_source",
    "source_setup",
    "real_source",
    "render_sources",
    "Source",
    "CatalogSun",
    "load_sources",
    "read_catalog",
    "real_split",
    "SPLITS",
    "CropSampler",
    "CropConfig",
    "View",
    "draw_view",
    "render_view",
    "view_direction",
]

CACHE_SIZE = 720
"""Rendered sources kept in memory (least recently used first out; ~3.5 MB each at 512 x 1024 as
float16, ~7.5 MB at 768 x 1536): a run's sources are read from disk once, not once per crop."""
_CACHE: OrderedDict[str, tuple[np.ndarray, np.ndarray]] = OrderedDict()

METER_EPS = 1e-4
"""Luminance added inside the log of :func:`metered_gain` (radiance units), so black pixels stay finite."""


def metered_gain(view: np.ndarray, key: float, limit: float = 2.0**10) -> float:
    """Gain that brings the log-average luminance of linear ``view (H, W, 3)`` to ``key``.

    ``key / exp(mean(log(METER_EPS + Y)))`` (Reinhard et al., "Photographic tone reproduction",
    SIGGRAPH 2002), clipped to ``[1/limit, limit]``: a camera's average metering that a visible sun
    (a handful of pixels) does not throw off. ``key = 0.18`` is the log-average of crops of the real
    HDR panoramas in ``../shared/data/real`` at their stored scale (0.15-0.37 for city, sunrise, courtyard).
    """
    y = luminance(np.asarray(view, dtype=np.float32))
    logavg = float(np.exp(np.mean(np.log(METER_EPS + np.clip(y, 0.0, None)))))
    return float(np.clip(key / logavg, 1.0 / limit, limit))


SOURCE_FILES = {"scene": "scene.exr", "light": "light.exr", "meta": "source.json"}


@dataclass
class SourceConfig:
    """Renderer settings of rendered sources (recorded in each ``source.json``)."""

    height: int = 512
    spp: int = 8
    max_depth: int = 4
    light_height: int = 512
    target_height: int = 128
    p_sunsky: float = 0.6
    positions_per_block: int = 8
    block_length: float = 60.0
    tex_size: int = 64
    firefly_k: float = 10.0
    exclude_hdr: tuple[str, ...] = ()
    denoise: bool = False
    real_lighting: tuple[str, ...] = ()
    """Folders of real HDR panoramas added to the HDR lighting maps (:func:`lighting_files`)."""
    real_lighting_split: str = "train"
    """The split (:data:`SPLITS`) of :func:`real_split` those folders' panoramas are drawn from."""

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["exclude_hdr"] = list(self.exclude_hdr)
        # recorded only when used, so the records of earlier renders stay as they were
        if not self.denoise:
            d.pop("denoise")
        if self.real_lighting:
            d["real_lighting"] = [str(Path(f).resolve()) for f in self.real_lighting]
        else:
            d.pop("real_lighting")
            d.pop("real_lighting_split")
        return d


def lighting_files(config: SourceConfig, hdr_dir: Path | None = None) -> tuple[list[Path], dict[str, CatalogSun]]:
    """The HDR maps rendered sources draw from: ``hdr_dir``'s EXRs (default: the shipped maps) plus the real
    panoramas of ``config.real_lighting`` in the split ``config.real_lighting_split`` (:func:`of_split`), less
    ``config.exclude_hdr``; and the catalogued sun of each real one (``{stem: CatalogSun}``, from its folder's
    ``catalog.json``).

    A real map's brightest spot is often not its sun (a street lamp at night, the moon, a bright cloud), so
    where the catalogue states the sun, the rendered source takes the catalogue's (:func:`source_setup`).
    """
    return _lighting_files(
        str(hdr_dir or HDR_DIR),
        tuple(str(Path(f).resolve()) for f in config.real_lighting),
        config.real_lighting_split,
        tuple(config.exclude_hdr),
    )


@functools.cache
def _lighting_files(
    hdr_dir: str, folders: tuple[str, ...], split: str, exclude: tuple[str, ...]
) -> tuple[list[Path], dict[str, CatalogSun]]:
    if split not in SPLITS:
        raise InputError(f"unknown split '{split}' (expected one of {', '.join(SPLITS)})")
    files = [f for f in sorted(Path(hdr_dir).glob("*.exr")) if f.stem not in exclude]
    suns: dict[str, CatalogSun] = {}
    for folder in folders:
        root = Path(folder)
        if not root.is_dir():
            raise InputError(f"{root}: no such folder of real HDR panoramas")
        found = [p for p in sorted(root.iterdir()) if p.suffix.lower() in (".exr", ".hdr") and p.stem not in exclude]
        chosen = of_split(found, split)
        if not chosen:
            raise InputError(f"{root}: no HDR panoramas (*.exr, *.hdr) of the '{split}' split")
        files += chosen
        catalog = read_catalog(root)
        suns.update({p.stem: catalog[p.stem] for p in chosen if p.stem in catalog})
    return files, suns


def source_setup(seed: int, index: int, config: SourceConfig, hdr_dir: Path | None = None) -> tuple[Any, Any, Any]:
    """The city block, camera and lighting of source ``index`` of the set ``seed`` (what :func:`render_source`
    renders): block ``index // positions_per_block``, a random walkable camera, a random lighting."""
    block = city_block(derive_seed(seed, int(index) // config.positions_per_block, 1), length=config.block_length)
    rng = np.random.default_rng(derive_seed(seed, index, 2))
    cam = sample_candidate(block, rng, int(rng.integers(6)), intrinsics_from_fov(math.radians(60.0), 64, 48), 64, 48)
    light = random_lighting(
        np.random.default_rng(derive_seed(seed, index, 3)),
        p_sunsky=config.p_sunsky,
        height=config.light_height,
        hdr_dir=hdr_dir or HDR_DIR,
        exclude=config.exclude_hdr,
        files=lighting_files(config, hdr_dir)[0] if config.real_lighting else None,
    )
    known = (
        lighting_files(config, hdr_dir)[1].get(Path(light.meta.get("file", "")).stem) if config.real_lighting else None
    )
    if known is not None:
        light.sun = light.rotation @ known.direction if known.visible else None
        light.meta["sun_from"] = "catalogue"
    return block, cam, light


def render_source(
    seed: int,
    index: int,
    out_dir: str | os.PathLike,
    config: SourceConfig | None = None,
    *,
    hdr_dir: Path | None = None,
) -> dict[str, Any]:
    """Render source ``index`` of the set ``seed`` into ``out_dir`` (``source.json`` written last).

    Block ``index // positions_per_block`` (the geometry of consecutive indices is shared), a
    random walkable camera position, a random lighting; returns the JSON record.
    """
    import time

    cfg = config or SourceConfig()
    t0 = time.perf_counter()
    mi = mitsuba()
    block_id = int(index) // cfg.positions_per_block
    block, cam, light = source_setup(seed, index, cfg, hdr_dir)
    scene = to_mitsuba(block, light.emitter(), tex_size=cfg.tex_size)
    sseed = derive_seed(seed, index, 4)
    img, fireflies = render_clean(
        scene,
        equirect_sensor(cam.position, np.eye(3), cfg.height, jitter=True, spp=cfg.spp, seed=sseed),
        cfg.spp,
        max_depth=cfg.max_depth,
        seed=sseed,
        protect=sun_mask_panorama(light.sun, np.eye(3), cfg.height),
        firefly_k=cfg.firefly_k,
        wrap=True,
        denoise=cfg.denoise,
    )
    env = np.asarray(rotate(light.panorama, light.rotation), dtype=np.float32)
    target = downsample(env, env.shape[0] // cfg.target_height)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prov = {"generator": "solidkit.synth.panocrops", "seed": int(seed), "index": int(index)}
    write_exr(out / SOURCE_FILES["scene"], img, {**prov, "frame": "scene"})
    write_exr(out / SOURCE_FILES["light"], target, {**prov, "frame": "scene"})
    record = {
        "kind": "rendered",
        "seed": int(seed),
        "index": int(index),
        "block_id": block_id,
        "block_seed": int(block.seed),
        "position": [float(v) for v in cam.position],
        "lighting": light.meta,
        "sun_scene": None if light.sun is None else [float(v) for v in light.sun],
        "fireflies": fireflies,
        "renderer": {"mitsuba": mi.__version__, "variant": variant(), **cfg.to_json()},
        "seconds": round(time.perf_counter() - t0, 2),
        "files": {k: v for k, v in SOURCE_FILES.items()},
    }
    atomic_write_text(out / SOURCE_FILES["meta"], json.dumps(record, indent=1))
    return record


def render_sources(
    root: str | os.PathLike,
    n: int,
    *,
    seed: int = 0,
    shard: tuple[int, int] = (0, 1),
    config: SourceConfig | None = None,
    progress: Any = None,
) -> dict[str, int]:
    """Render the missing sources ``0 .. n-1`` of shard ``shard`` into ``root/NNNNNN`` (resumable)."""
    from solidkit.synth.dataset import shard_range  # lazy: pulls in torch

    root = Path(root)
    cfg = config or SourceConfig()
    manifest = root / "sources.json"
    want = {"seed": int(seed), "config": cfg.to_json()}
    if manifest.is_file():
        old = json.loads(manifest.read_text())
        if old.get("seed") != want["seed"] or old.get("config") != want["config"]:
            raise InputError(f"{root}: holds sources of another seed or settings; use a new --out")
    else:
        root.mkdir(parents=True, exist_ok=True)
        atomic_write_text(manifest, json.dumps(want, indent=1))
    counts = {"rendered": 0, "skipped": 0}
    todo = shard_range(n, *shard)
    for k, i in enumerate(todo):
        d = root / f"{i:06d}"
        if (d / SOURCE_FILES["meta"]).is_file():
            counts["skipped"] += 1
        else:
            render_source(seed, i, d, cfg)
            counts["rendered"] += 1
        if progress:
            progress(k + 1, len(todo))
    return counts


@dataclass(frozen=True)
class CatalogSun:
    """A panorama's sun as its catalogue states it: ``visible`` and, when visible, the unit ``direction (3,)``
    in the panorama's own (scene) frame (conventions §2)."""

    visible: bool
    direction: np.ndarray


SPLITS = ("train", "val", "test")
SPLIT_FILE = Path(__file__).resolve().parents[1] / "assets" / "hdr_outdoor_split.json"
"""The split by whole panorama of the real outdoor panoramas (``../shared/data/real/hdr_outdoor``)."""


def real_split(path: Path = SPLIT_FILE) -> dict[str, str]:
    """``{panorama name: "train" | "val" | "test"}`` of the shipped split file."""
    data = json.loads(Path(path).read_text())
    return {name: split for split in SPLITS for name in data[split]}


def of_split(files: list[Path], split: str) -> list[Path]:
    """The panoramas of ``files`` in ``split`` of the shipped split file (:func:`real_split`). Where the split
    file covers the folder (it lists one of ``files``), a panorama it does not list (one added later) belongs to
    ``train``, so it never leaks into validation or test; files it does not cover at all are kept."""
    table = real_split()
    if not any(p.stem in table for p in files):
        return list(files)
    return [p for p in files if table.get(p.stem, "train") == split]


def read_catalog(root: str | os.PathLike) -> dict[str, CatalogSun]:
    """``{file stem: CatalogSun}`` from ``root/catalog.json`` (records with ``file``, ``sun_visible`` and, when
    visible, ``sun_azimuth_deg`` / ``sun_elevation_deg`` in the project's convention); ``{}`` when absent."""
    path = Path(root) / "catalog.json"
    if not path.is_file():
        return {}
    try:
        records = json.loads(path.read_text())
        out = {}
        for r in records:
            visible = bool(r["sun_visible"])
            d = (
                np.asarray(
                    direction_from_angles(
                        math.radians(float(r["sun_azimuth_deg"])), math.radians(float(r["sun_elevation_deg"]))
                    ),
                    np.float32,
                )
                if visible
                else np.zeros(3, np.float32)
            )
            out[Path(r["file"]).stem] = CatalogSun(visible, d)
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a panorama catalogue ({type(exc).__name__}: {exc})") from None
    return out


@dataclass
class Source:
    """One panorama to crop: ``scene (H, 2H, 3)`` and ``light (h, 2h, 3)`` linear, both in the scene frame.

    Rendered sources are read from ``path`` on each :meth:`load` (hundreds do not fit in memory);
    real ones keep their arrays.
    """

    name: str
    kind: str
    path: Path | None = None
    scene: np.ndarray | None = None
    light: np.ndarray | None = None
    sun: CatalogSun | None = None
    """The sun measured independently of this module (a folder's ``catalog.json``); ``None``: detect it."""

    def load(self) -> tuple[np.ndarray, np.ndarray]:
        """``(scene, light)`` float32 arrays."""
        if self.scene is not None and self.light is not None:
            return self.scene, self.light
        assert self.path is not None
        key = str(self.path)
        hit = _CACHE.get(key)
        if hit is None:
            scene = read_exr(self.path / SOURCE_FILES["scene"])[0][..., :3]
            # float16 halves the memory; the crop is tonemapped (saturating near 1), so the sun may clip
            hit = (np.minimum(scene, 6.0e4).astype(np.float16), read_exr(self.path / SOURCE_FILES["light"])[0][..., :3])
            _CACHE[key] = hit
            while len(_CACHE) > CACHE_SIZE:
                _CACHE.popitem(last=False)
        else:
            _CACHE.move_to_end(key)
        return hit[0].astype(np.float32), hit[1]


def _rendered_sun(meta: Path) -> CatalogSun | None:
    """The catalogued sun a rendered source was lit by (its ``source.json``), ``None`` where its lighting's
    sun is to be detected (Mitsuba's sun and sky, the shipped maps)."""
    try:
        record = json.loads(meta.read_text())
        if record.get("lighting", {}).get("sun_from") != "catalogue":
            return None
        sun = record["sun_scene"]
        return CatalogSun(sun is not None, np.asarray(sun if sun is not None else np.zeros(3), np.float32))
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{meta}: not a rendered source's record ({type(exc).__name__}: {exc})") from None


def real_source(path: str | os.PathLike, target_height: int = 128, sun: CatalogSun | None = None) -> Source:
    """A real HDR panorama (EXR or Radiance HDR) as its own scene and global target (area-downsampled to
    ``target_height``); ``sun``: its catalogued sun, if any."""
    pano = read_panorama(path)
    if pano.shape[0] % target_height:
        raise InputError(f"{path}: need an equirect panorama whose height is a multiple of {target_height}")
    return Source(Path(path).stem, "real", Path(path), pano, downsample(pano, pano.shape[0] // target_height), sun)


def load_sources(root: str | os.PathLike, exclude: tuple[str, ...] = (), split: str | None = None) -> list[Source]:
    """Every complete rendered source under ``root`` (sorted; read lazily), or the real HDR panoramas in it
    (``*.exr``, ``*.hdr``; with their sun from ``root/catalog.json`` when there is one).

    ``exclude``: names (folder names or file stems) to leave out, e.g. a held-out real panorama.
    ``split``: one of :data:`SPLITS`: keep only the real panoramas of that split (:func:`of_split`);
    rendered sources (split by folder) are not filtered.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: no such folder of panoramas")
    if split is not None and split not in SPLITS:
        raise InputError(f"unknown split '{split}' (expected one of {', '.join(SPLITS)})")
    metas = sorted(root.glob(f"*/{SOURCE_FILES['meta']}"))
    if metas:
        return [
            Source(m.parent.name, "rendered", m.parent, sun=_rendered_sun(m))
            for m in metas
            if m.parent.name not in exclude
        ]
    files = [p for p in sorted(root.iterdir()) if p.suffix.lower() in (".exr", ".hdr") and p.stem not in exclude]
    if split is not None:
        files = of_split(files, split)
    if not files:
        raise InputError(
            f"{root}: no rendered sources (*/source.json) and no HDR panoramas"
            + (f" of the '{split}' split" if split else "")
        )
    catalog = read_catalog(root)
    return [real_source(p, sun=catalog.get(p.stem)) for p in files]


@dataclass
class CropConfig:
    """Ranges of the crop parameters (degrees, stops).

    ``exposure_key``: metered exposure (:func:`metered_gain`) before the ``exposure_stops`` jitter;
    ``None`` keeps the gain at 1 (the paper's fixed exposure of the HDR values as stored).
    """

    width: int = 320
    height: int = 240
    hfov_deg: tuple[float, float] = (50.0, 70.0)
    pitch_deg: tuple[float, float] = (-10.0, 15.0)
    roll_deg: tuple[float, float] = (-3.0, 3.0)
    exposure_stops: tuple[float, float] = (-0.5, 0.5)
    white_balance: float = 0.08
    flip: bool = True
    exposure_key: float | None = None


class CropSampler:
    """Crops of ``sources``: item ``i`` is a pure function of ``(seed, i)`` (see module docstring).

    ``__call__(i)`` returns a dict of numpy arrays: ``image (240, 320, 3)`` in [0, 1] (tonemapped),
    ``K (3, 3)``, ``pitch``, ``roll``, ``yaw`` (radians), ``sky (128, 256, 3)`` radiance in the
    camera's panorama frame, ``sun_dir (3,)`` and ``sun_visible`` (the default detector,
    :func:`solidkit.envmap.detect_sun`, on the target), ``source`` (name), ``gain`` (the mean of the
    exposure x white-balance gain applied to scene and target).
    """

    def __init__(self, sources: list[Source], seed: int = 0, config: CropConfig | None = None) -> None:
        if not sources:
            raise InputError("no panoramas to crop")
        self.sources = sources
        self.seed = int(seed)
        self.config = config or CropConfig()

    def __len__(self) -> int:
        return len(self.sources)

    def __call__(self, index: int) -> dict[str, Any]:
        c = self.config
        rng = np.random.default_rng(derive_seed(self.seed, int(index), 11))
        src = self.sources[int(index) % len(self.sources)]
        view = draw_view(rng, c)
        scene, light = src.load()
        image, K, roll, gain = render_view(scene, view, c)
        sky = np.asarray(rotate(light, np.asarray(rotation_y(view.yaw)).T), dtype=np.float32) * gain.astype(np.float32)
        if view.flip:
            sky = sky[:, ::-1]
        if src.sun is not None:  # the catalogue's sun, turned as the crop turned the panorama
            found, direction = src.sun.visible, view_direction(src.sun.direction, view)
        else:
            sun = detect_sun(sky)
            found, direction = sun.found, np.asarray(sun.direction if sun.found else np.zeros(3))
        return {
            "image": image,
            "K": K,
            "pitch": np.float32(view.pitch),
            "roll": np.float32(roll),
            "yaw": np.float32(view.yaw),
            "sky": np.ascontiguousarray(sky, dtype=np.float32),
            "sun_dir": (direction if found else np.zeros(3)).astype(np.float32),
            "sun_visible": np.float32(found),
            "source": src.name,
            "gain": np.float32(np.mean(gain)),
        }


@dataclass(frozen=True)
class View:
    """A crop's camera and photometry: ``yaw``, ``pitch``, ``roll``, ``hfov`` (radians), ``gain (3,)`` (exposure x
    white balance before metering) and ``flip`` (mirror the result horizontally)."""

    yaw: float
    pitch: float
    roll: float
    hfov: float
    gain: np.ndarray
    flip: bool


def view_direction(d_scene: np.ndarray, view: View) -> np.ndarray:
    """A scene-frame direction ``d_scene (3,)`` in the camera's panorama frame of ``view``:
    ``R_y(yaw)^T d`` (conventions §2), ``x`` negated when the view is flipped; float64 ``(3,)``."""
    d = np.asarray(rotation_y(view.yaw)).T @ np.asarray(d_scene, np.float64)
    if view.flip:
        d[0] = -d[0]
    return d


def draw_view(rng: np.random.Generator, c: CropConfig) -> View:
    """A :class:`View` drawn with ``rng`` within the ranges of ``c``."""
    yaw = rng.uniform(-math.pi, math.pi)
    pitch = math.radians(rng.uniform(*c.pitch_deg))
    roll = math.radians(rng.uniform(*c.roll_deg))
    hfov = math.radians(rng.uniform(*c.hfov_deg))
    gain = 2.0 ** rng.uniform(*c.exposure_stops) * np.exp(rng.uniform(-c.white_balance, c.white_balance, 3))
    return View(yaw, pitch, roll, hfov, gain, bool(c.flip and rng.random() < 0.5))


def render_view(scene: np.ndarray, view: View, c: CropConfig) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The crop of ``scene (H, 2H, 3)`` (linear, scene frame) seen by ``view`` at ``c.width x c.height``:
    ``(image (h, w, 3)`` tonemapped in [0, 1], ``K (3, 3)``, ``roll``, ``gain (3,))`` with the flip applied
    (image mirrored, principal point mirrored, roll negated) and ``gain`` metered when ``c.exposure_key`` is set."""
    # conventions §4: pitch positive = up; R maps camera rays to the scene frame
    R = np.asarray(rotation_from_ypr(view.yaw, view.pitch, view.roll))
    K = intrinsics_from_fov(view.hfov, c.width, c.height)
    linear = perspective_crop(scene, R, (c.width, c.height), K=K, interp="linear")
    gain = view.gain * metered_gain(linear, c.exposure_key) if c.exposure_key is not None else view.gain
    image = np.clip(np.asarray(tonemap(np.clip(linear, 0, None) * gain.astype(np.float32))), 0.0, 1.0)
    roll = view.roll
    if view.flip:
        image = image[:, ::-1]
        K = K.copy()
        K[0, 2] = c.width - 1 - K[0, 2]
        roll = -roll
    return np.ascontiguousarray(image, dtype=np.float32), K.astype(np.float32), roll, gain
