"""The images align/ reads from an ingested campaign: per capture, its shots, products and panoramas.

Nothing here writes. Every panorama is in the capture's level frame (conventions §8) unless a
rotation is given, in which case it is made in one resampling from the original (dual-fisheye
unwarp or equirect rotation through :mod:`solidkit.capture.unwarp` / :mod:`solidkit.envmap.resample`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.camera.lens import load_profile, profile_for_metadata
from solidkit.camera.metadata import CaptureMetadata, level_rotation
from solidkit.capture.frame_merge import read_ldr_codes
from solidkit.capture.manifest import Manifest, Probe, Scene, Shot
from solidkit.capture.unwarp import default_out_height, load_vignetting, unwarp_srgb8
from solidkit.envmap.io import read_exr, read_ldr
from solidkit.envmap.resample import rotate
from solidkit.errors import InputError

__all__ = [
    "Capture",
    "captures_of",
    "camera_probe_of",
    "photo_shot_of",
    "levelling_of",
    "load_normal_panorama",
    "normal_shot_of",
    "exposure_stops",
    "NORMAL_EXPOSURE_S",
]

NORMAL_EXPOSURE_S = 1.0 / 2500.0
"""The paper's probe exposure; the single shot closest to it (in stops) is a capture's LDR probe."""


@dataclass
class Capture:
    """One Theta position of a scene, as ingested."""

    scene: str
    probe: Probe
    normal: Shot | None
    sun_frame_path: str | None
    hdr_path: str | None
    hdr_inputs: list[str]

    @property
    def id(self) -> str:
        return self.probe.id


def photo_shot_of(manifest: Manifest, scene: Scene) -> Shot | None:
    """The scene's reference photo (``Scene.photo``, else its first photo)."""
    sha = getattr(scene, "photo", None) or (scene.photos[0] if scene.photos else None)
    return None if sha is None else manifest.shot(sha)


def camera_probe_of(scene: Scene) -> str | None:
    """The camera-position capture: ``Scene.camera_probe``, a probe with role 'camera', or one named 'cam'."""
    if getattr(scene, "camera_probe", None):
        return scene.camera_probe
    for p in scene.probes:
        if getattr(p, "role", "probe") == "camera" or p.id.lower() in ("cam", "camera"):
            return p.id
    return None


def captures_of(manifest: Manifest, scene: Scene) -> list[Capture]:
    """The scene's captures with their normal shot, sun frame and first HDR product (camera position first)."""
    cam = camera_probe_of(scene)
    out = []
    for p in sorted(scene.probes, key=lambda p: (p.id != cam, p.id)):
        normal = normal_shot_of(manifest, p)
        sun = hdr = None
        hdr_inputs: list[str] = []
        for prod in manifest.products:
            if prod.scene != scene.id or prod.probe != p.id or prod.error or not prod.path:
                continue
            if prod.kind == "sun_frame" and sun is None and prod.layout == "equirect":
                sun = prod.path
            elif prod.kind == "hdr" and hdr is None and prod.layout == "equirect":
                hdr, hdr_inputs = prod.path, list(prod.inputs)
        out.append(Capture(scene.id, p, normal, sun, hdr, hdr_inputs))
    return out


def normal_shot_of(manifest: Manifest, probe: Probe) -> Shot | None:
    """The shot a capture's LDR probe is made from: its single exposure (else bracket member) nearest to the
    protocol's :data:`NORMAL_EXPOSURE_S` in stops (None: no shot with an exposure time)."""
    shots = [manifest.shot(s) for s in probe.shots]
    singles = [s for s in shots if s.kind == "probe" and s.metadata.get("exposure_time")]
    pool = singles or [s for s in shots if s.kind == "bracket_member" and s.metadata.get("exposure_time")]
    return min(pool, key=lambda s: abs(exposure_stops(s)), default=None)


def exposure_stops(shot: Shot) -> float:
    """How many stops longer than the protocol's :data:`NORMAL_EXPOSURE_S` the shot's exposure time is."""
    return math.log2(float(shot.metadata["exposure_time"]) / NORMAL_EXPOSURE_S)


def levelling_of(shot: Shot) -> tuple[float, float, np.ndarray]:
    """``(pitch_deg, roll_deg, R_level)`` that ingest's products of this shot were levelled with."""
    meta = CaptureMetadata.model_validate(shot.metadata)
    if meta.image_type == "dual_fisheye_upright" or meta.pitch_deg is None or meta.roll_deg is None:
        return 0.0, 0.0, np.eye(3)
    R = np.asarray(level_rotation(meta), np.float64)
    if np.allclose(R, np.eye(3), atol=1e-12):
        return 0.0, 0.0, R
    return float(meta.pitch_deg), float(meta.roll_deg), R


def _lens(campaign: Path, manifest: Manifest, md: dict[str, Any]) -> Any:
    rec = manifest.lens_profile
    if rec:
        return load_profile(rec["name"] if rec.get("kind") == "shipped" else campaign / rec["path"])
    return profile_for_metadata(md.get("model"), int(md.get("width") or 0), int(md.get("height") or 0))


def _vignetting(campaign: Path, manifest: Manifest) -> Any:
    if not manifest.vignetting:
        return None
    return load_vignetting(campaign / manifest.vignetting["path"])


def load_normal_panorama(
    campaign: Path, manifest: Manifest, shot: Shot, R_extra: np.ndarray | None = None, height: int | None = None
) -> np.ndarray:
    """The shot as an 8-bit sRGB panorama ``(H, 2H, 3)`` uint8, levelled and then rotated by ``R_extra``.

    Dual-fisheye: one unwarp with ``R_extra @ R_level`` (:func:`solidkit.capture.unwarp.unwarp_srgb8`);
    equirect: one rotation of the decoded image.
    """
    md = shot.metadata
    _, _, R_level = levelling_of(shot)
    R = R_level if R_extra is None else np.asarray(R_extra) @ R_level
    codes = read_ldr_codes(campaign / shot.original)
    if codes.dtype != np.uint8:
        codes = np.round(codes.astype(np.float32) / 257.0).astype(np.uint8)
    layout = md.get("image_type")
    if layout in ("dual_fisheye", "dual_fisheye_upright"):
        h, w = codes.shape[:2]
        out_h = height or default_out_height(w)
        return unwarp_srgb8(codes, _lens(campaign, manifest, md), out_h, R, vignetting=_vignetting(campaign, manifest))
    if layout == "equirect":
        if np.allclose(R, np.eye(3), atol=1e-12) and (height is None or height == codes.shape[0]):
            return codes
        out = rotate(codes.astype(np.float32), R, "linear", height)
        return np.clip(np.round(out), 0, 255).astype(np.uint8)
    raise InputError(f"{shot.original}: image type {layout!r} is not a panorama")


def read_sun_frame(campaign: Path, path: str) -> np.ndarray:
    """A sun-frame product as encoded float RGB in ``[0, 1]``."""
    return read_ldr(campaign / path)


def read_hdr(campaign: Path, path: str) -> np.ndarray:
    """An HDR product (linear float32)."""
    img, _ = read_exr(campaign / path)
    return img
