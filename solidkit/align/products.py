"""Aligned probe products: every capture turned into the photo's panorama frame.

Per capture, under ``CAMPAIGN/align/<scene>/<probe>/`` (paths in ``ProbeAlignment.products``):

- ``ldr_full.png``: the normal shot (the paper's 1/2500 s probe), 8-bit sRGB, unwarped once with
  ``ProbeAlignment.rotation`` (no second resampling), at ingest's panorama size;
- ``ldr_256.png``: the paper's local-probe format, 256x128 8-bit sRGB: ``ldr_full`` decoded to
  linear, area-resampled on the sphere (:func:`solidkit.envmap.resample.resize`), re-encoded;
- ``saturation_full.png`` / ``saturation_256.png``: 255 where the normal shot clipped (any
  channel at code 250 or above; at 256x128 a pixel is marked when any of its footprint clipped);
- ``hdr_full.exr`` / ``hdr_256.exr``: the merged bracket (ingest's HDR, levelled by the
  metadata) rotated into the photo's panorama frame and area-resized, where a bracket exists.

Each capture's recipe (inputs' sha256, yaw, levelling, sizes, solidkit version) is hashed into
``recipe.json`` beside the files; an unchanged recipe with its files present is not rebuilt.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from solidkit import __version__
from solidkit.align.captures import captures_of, levelling_of, load_normal_panorama, read_hdr
from solidkit.align.schema import ProbeProducts, SceneAlignment, body_to_pano
from solidkit.capture.manifest import Manifest, Scene
from solidkit.envmap.io import srgb_decode, srgb_encode, write_exr, write_ldr
from solidkit.envmap.resample import resize, rotate
from solidkit.fsutil import atomic_write_text, sha256_file

__all__ = ["write_products", "SATURATION_CODE"]

SATURATION_CODE = 250


def _recipe_hash(recipe: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(recipe, sort_keys=True).encode()).hexdigest()[:16]


def write_products(
    campaign: Path,
    manifest: Manifest,
    scene: Scene,
    sa: SceneAlignment,
    settings: Any,
    previous: Any = None,
    log: Callable[[str], None] = lambda s: None,
) -> None:
    """Write the aligned products of every capture of ``sa`` whose yaw is known; fills ``products``."""
    caps = {c.id: c for c in captures_of(manifest, scene)}
    out_h = int(settings.probe_height)
    for pa in sa.probes:
        cap = caps.get(pa.id)
        if cap is None or pa.yaw_deg is None:
            continue
        rel = Path("align") / scene.id / pa.id
        root = campaign / rel
        recipe = {
            "tool": "solidkit.align.products",
            "solidkit_version": __version__,
            "yaw_deg": round(pa.yaw_deg, 6),
            "levelling": [round(pa.levelling.pitch_deg, 6), round(pa.levelling.roll_deg, 6)],
            "normal": cap.normal.sha256 if cap.normal else None,
            "hdr": sha256_file(campaign / cap.hdr_path) if cap.hdr_path else None,
            "probe_height": out_h,
            "saturation_code": SATURATION_CODE,
        }
        h = _recipe_hash(recipe)
        files = ProbeProducts()
        if cap.normal is not None:
            files.ldr_full, files.ldr_256 = f"{rel.as_posix()}/ldr_full.png", f"{rel.as_posix()}/ldr_256.png"
            files.saturation_full, files.saturation_256 = (
                f"{rel.as_posix()}/saturation_full.png",
                f"{rel.as_posix()}/saturation_256.png",
            )
        if cap.hdr_path:
            files.hdr_full, files.hdr_256 = f"{rel.as_posix()}/hdr_full.exr", f"{rel.as_posix()}/hdr_256.exr"
        done = root / "recipe.json"
        paths = [p for p in files.model_dump().values() if p]
        if done.is_file() and all((campaign / p).is_file() for p in paths):
            try:
                if json.loads(done.read_text()).get("hash") == h:
                    pa.products = files
                    continue
            except ValueError:
                pass
        # body -> photo panorama frame, applied on top of the levelling each source was made with
        R_total = body_to_pano(pa.yaw_deg, pa.levelling.pitch_deg, pa.levelling.roll_deg)
        if cap.normal is not None:
            assert files.ldr_full is not None and files.ldr_256 is not None  # named above for a normal shot
            assert files.saturation_full is not None and files.saturation_256 is not None
            ldr = load_normal_panorama(campaign, manifest, cap.normal, R_total @ levelling_of(cap.normal)[2].T)
            write_ldr(campaign / files.ldr_full, ldr)
            lin = np.asarray(srgb_decode(ldr.astype(np.float32) / 255.0), np.float32)
            small = np.clip(np.asarray(resize(lin, out_h)), 0.0, 1.0)
            write_ldr(campaign / files.ldr_256, np.round(np.asarray(srgb_encode(small)) * 255.0).astype(np.uint8))
            sat = (ldr.max(axis=2) >= SATURATION_CODE).astype(np.float32)
            write_ldr(campaign / files.saturation_full, (sat * 255).astype(np.uint8))
            sat_small = np.asarray(resize(sat, out_h)) > 0.0
            write_ldr(campaign / files.saturation_256, (sat_small * 255).astype(np.uint8))
        if cap.hdr_path:
            assert files.hdr_full is not None and files.hdr_256 is not None  # named above for an HDR product
            hdr = read_hdr(campaign, cap.hdr_path)
            R_hdr = R_total @ levelling_of(manifest.shot(cap.hdr_inputs[0]))[2].T
            full = np.clip(np.asarray(rotate(hdr, R_hdr, "linear")), 0.0, None).astype(np.float32)
            meta = {
                "frame": "photo panorama frame (conventions §2, §8)",
                "scene": scene.id,
                "probe": pa.id,
                "yaw_deg": pa.yaw_deg,
                "source": cap.hdr_path,
            }
            write_exr(campaign / files.hdr_full, full, meta)
            write_exr(campaign / files.hdr_256, np.asarray(resize(full, out_h), np.float32), meta)
        atomic_write_text(done, json.dumps({"hash": h, "recipe": recipe}, indent=1) + "\n")
        pa.products = files
        log(f"{scene.id}/{pa.id}: products written (yaw {pa.yaw_deg:+.2f} deg)")
