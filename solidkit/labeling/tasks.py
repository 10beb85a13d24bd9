"""What there is to label in a campaign: the items of each task, built from the manifest
(:func:`solidkit.capture.manifest.load_manifest`) and, where it exists, align/'s automatic
result (``CAMPAIGN/align/alignment.json``, contract C3, passed in as a plain dict because
align/ sits above labeling/ in the layers).

Tasks and their label kinds (contract C2):

- ``sun``: one item per Theta position with a ``sun_frame`` product; the annotator marks the
  sun's centre in that capture's level frame.
- ``probe_pixel``: one item per probe position (role ``probe``) of a scene with a photo; the
  pixel of the photo where the probe stood.
- ``heading``: one item per position of a scene with a photo; the yaw taking the capture's
  level frame to the photo's panorama frame (``d_P = R_y(yaw) d_L``, conventions "Heading and
  alignment"), shown as the photo's field of view outlined on the capture's panorama.

Every path served is resolved (symlinks followed) and must lie inside the campaign folder.
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.calibration.camera import intrinsics_from_exif
from solidkit.camera.metadata import CaptureMetadata
from solidkit.capture.manifest import Manifest, load_manifest
from solidkit.envmap.coords import angles_from_direction, rotation_from_ypr
from solidkit.errors import InputError, SolidkitError
from solidkit.flags import Flag
from solidkit.labeling.images import ImageRef

__all__ = ["TASKS", "Item", "CampaignIndex", "fov_outline", "inside"]

TASKS = ("sun", "probe_pixel", "heading")
_HDR = {".exr"}


def inside(root: Path, path: Path) -> Path | None:
    """``path`` resolved (symlinks followed) if it is a regular file inside ``root``; else None."""
    try:
        real = path.resolve(strict=True)
    except (OSError, RuntimeError):
        return None
    if not real.is_relative_to(root) or not real.is_file():
        return None
    return real


def fov_outline(
    K: np.ndarray, size: tuple[int, int], pitch_deg: float, roll_deg: float, n: int = 12
) -> list[list[float]]:
    """The photo's border as directions in its panorama frame: ``[[azimuth_deg, elevation_deg], ...]``.

    Parameters
    ----------
    K : (3, 3) array
        Intrinsics of the full-resolution photo (pixels, conventions §1).
    size : (width, height)
        Photo size in pixels.
    pitch_deg, roll_deg : float
        The photo camera's orientation in its panorama frame, ``R_cam = R(0, pitch, roll)`` (§4).
    n : int
        Points per edge (the edges are curves on the sphere).

    Returns
    -------
    list of [azimuth_deg, elevation_deg]
        ``4 n`` points around the frame's outer pixel edges, clockwise from the top-left corner
        (corners at indices 0, n, 2n, 3n: top-left, top-right, bottom-right, bottom-left).
    """
    w, h = size
    t = np.linspace(0.0, 1.0, n, endpoint=False)
    # pixel edges (not centres): the image spans [-0.5, W - 0.5] x [-0.5, H - 0.5] (§1)
    x0, x1, y0, y1 = -0.5, w - 0.5, -0.5, h - 0.5
    xs = np.concatenate([x0 + (x1 - x0) * t, np.full(n, x1), x1 - (x1 - x0) * t, np.full(n, x0)])
    ys = np.concatenate([np.full(n, y0), y0 + (y1 - y0) * t, np.full(n, y1), y1 - (y1 - y0) * t])
    rays = np.linalg.solve(np.asarray(K, dtype=np.float64), np.stack([xs, ys, np.ones_like(xs)]))
    R = np.asarray(rotation_from_ypr(0.0, math.radians(pitch_deg), math.radians(roll_deg)), dtype=np.float64)
    d = (R @ rays).T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    az, el = angles_from_direction(d)
    return [[round(math.degrees(a), 4), round(math.degrees(e), 4)] for a, e in zip(az, el)]


def _flags(aprobe: dict[str, Any], *, pixel: bool) -> list[str]:
    """align/'s flags of a probe that concern its pixel (codes ``pixel_...``) or the rest (yaw, cues)."""
    return [f for f in aprobe.get("flags", []) if Flag.parse(f).code.startswith("pixel") == pixel]


@dataclass
class Item:
    """One thing to label: ``kind`` + ``key`` (the label's address in the store) and what the
    browser needs to show it (JSON-able ``view``), with align/'s proposal and flags."""

    kind: str
    key: str
    scene: str
    probe: str
    title: str
    view: dict[str, Any] = field(default_factory=dict)
    proposal: dict[str, Any] | None = None
    flags: list[str] = field(default_factory=list)


class CampaignIndex:
    """The campaign's images and task items (read once; cheap to rebuild).

    Parameters
    ----------
    campaign_dir : path
        The campaign folder (``manifest.json``).
    alignment : dict, optional
        ``CAMPAIGN/align/alignment.json`` as validated by ``solidkit.align.schema`` and dumped
        to a dict; None when align/ has not run (no proposals then).
    """

    def __init__(self, campaign_dir: str | os.PathLike, alignment: dict[str, Any] | None = None):
        self.root = Path(campaign_dir).resolve()
        if not (self.root / "manifest.json").is_file():
            raise InputError(f"{campaign_dir}: no manifest.json (run `solidkit ingest` first)")
        self.manifest: Manifest = load_manifest(self.root)
        self.alignment = alignment or {}
        self.images: dict[str, ImageRef] = {}
        self.items: dict[str, dict[str, Item]] = {t: {} for t in TASKS}
        self.problems: list[str] = []  # missing/unsafe files, shown in the app
        self._align_scenes = {s["id"]: s for s in self.alignment.get("scenes", [])}
        self._build()

    # -- images ------------------------------------------------------------------------------
    def _image(self, rel: str | None, layout: str) -> ImageRef | None:
        if not rel:
            return None
        real = inside(self.root, self.root / rel)
        if real is None:
            self.problems.append(f"{rel}: missing or outside the campaign; not served")
            return None
        st = real.stat()  # the id changes with the file, so a browser never shows a stale cached copy
        img_id = (
            "img-"
            + hashlib.sha256(f"{real.relative_to(self.root)}:{st.st_size}:{st.st_mtime_ns}".encode()).hexdigest()[:16]
        )
        ref = ImageRef(id=img_id, path=real, layout=layout, hdr=real.suffix.lower() in _HDR)
        self.images[img_id] = ref
        return ref

    # -- building ----------------------------------------------------------------------------
    def _build(self) -> None:
        products: dict[tuple[str, str, str], Any] = {}
        for p in sorted(self.manifest.products, key=lambda p: p.id):
            if p.path and not p.error:
                products.setdefault((p.scene, p.probe, p.kind), p)
        for scene in sorted(self.manifest.scenes, key=lambda s: s.id):
            asc = self._align_scenes.get(scene.id, {})
            photo = self._photo(scene, asc)
            ids = [pr.id for pr in scene.probes]
            cam_probe = (
                scene.camera_probe
                or asc.get("camera_probe")
                or next((pr.id for pr in scene.probes if pr.role == "camera"), None)
                or next((n for n in ("cam", "camera") if n in ids), None)  # manifests before field notes (C1)
            )
            for probe in scene.probes:
                key = f"{scene.id}/{probe.id}"
                aprobe: dict[str, Any] = next((p for p in asc.get("probes", []) if p.get("id") == probe.id), {})
                role = "camera" if probe.id == cam_probe or probe.role == "camera" else "probe"
                label = f"{scene.id} · {probe.id}" + (" (camera position)" if role == "camera" else "")
                sun = products.get((scene.id, probe.id, "sun_frame"))
                ref = self._image(sun.path, "equirect") if sun else None
                if ref is not None:
                    self.items["sun"][key] = self._sun_item(key, scene.id, probe.id, label, ref, asc, probe.warnings)
                if photo is None:
                    continue
                if role == "probe":
                    self.items["probe_pixel"][key] = self._pixel_item(key, scene.id, probe, label, photo, aprobe)
                hdr = products.get((scene.id, probe.id, "hdr"))
                pano = (self._image(hdr.path, "equirect") if hdr else None) or ref
                if pano is not None:
                    self.items["heading"][key] = self._heading_item(key, scene.id, probe.id, label, pano, photo, aprobe)

    def _photo(self, scene, asc: dict) -> dict[str, Any] | None:
        sha = scene.photo or (scene.photos[0] if scene.photos else None)
        if sha is None:
            return None
        try:
            shot = self.manifest.shot(sha)
        except KeyError:
            self.problems.append(f"{scene.id}: photo {sha[:12]} not in the manifest's shots")
            return None
        ref = self._image(shot.original, "perspective")
        if ref is None:
            return None
        info = asc.get("photo") or {}
        meta = shot.metadata or {}
        size = info.get("size") or [meta.get("width"), meta.get("height")]
        K, K_source = info.get("K_full"), info.get("K_source") or ("alignment" if info.get("K_full") else "")
        if K is None and size[0] and size[1]:
            try:
                K_arr, K_source = intrinsics_from_exif(CaptureMetadata.model_validate(meta))
                K = K_arr.tolist()
            except (SolidkitError, ValueError):
                K, K_source = None, "unknown (no focal length in EXIF; run align or calibrate)"
        pitch = info.get("pitch_deg", scene.photo_pitch_deg)
        roll = info.get("roll_deg", scene.photo_roll_deg)
        assumed = pitch is None or roll is None
        pitch, roll = pitch or 0.0, roll or 0.0
        outline = fov_outline(np.asarray(K), tuple(size), pitch, roll) if K is not None and size[0] else None
        return {
            "image": ref.id, "size": size, "K": K, "K_source": K_source, "pitch_deg": pitch, "roll_deg": roll,
            "pose_assumed": assumed, "outline": outline,
        }  # fmt: skip

    def _sun_item(self, key, scene_id, probe_id, label, ref, asc, warnings) -> Item:
        cap = next((c for c in (asc.get("sun") or {}).get("captures", []) if c.get("probe") == probe_id), None)
        proposal, flags, candidates, ephem = None, list(warnings), [], None
        if cap is not None:
            flags += cap.get("flags", [])
            if cap.get("found") and cap.get("azimuth_deg") is not None:
                proposal = {k: cap.get(k) for k in ("found", "azimuth_deg", "elevation_deg", "uncertainty_deg")}
            elif cap.get("found") is False:
                proposal = {"found": False, "reason": cap.get("reason", "")}
            candidates = [
                {k: c.get(k) for k in ("azimuth_deg", "elevation_deg", "size_deg", "chosen", "reasons")}
                for c in cap.get("candidates", [])
            ]
            if cap.get("ephemeris"):
                ephem = {"elevation_deg": cap["ephemeris"].get("elevation_deg")}
        view = {"image": ref.id, "candidates": candidates, "ephemeris": ephem, "reason": (cap or {}).get("reason", "")}
        return Item("sun", key, scene_id, probe_id, label, view, proposal, flags)

    def _pixel_item(self, key, scene_id, probe, label, photo, aprobe) -> Item:
        proposal, source = None, None
        if aprobe.get("pixel_full"):
            proposal, source = aprobe["pixel_full"], aprobe.get("pixel_source") or "align"
        elif probe.photo_pixel:
            proposal, source = probe.photo_pixel, "field_notes"
        view = {
            "photo": photo, "note": probe.note, "proposal_source": source,
            "geometry": aprobe.get("pixel_geometry"), "geometry_error_px": aprobe.get("pixel_error_px"),
        }  # fmt: skip
        prop = {"x": float(proposal[0]), "y": float(proposal[1])} if proposal else None
        return Item("probe_pixel", key, scene_id, probe.id, label, view, prop, _flags(aprobe, pixel=True))

    def _heading_item(self, key, scene_id, probe_id, label, pano, photo, aprobe) -> Item:
        yaw = aprobe.get("yaw_deg")
        cues = {
            n: {k: c.get(k) for k in ("yaw_deg", "weight", "ok", "detail")}
            for n, c in (aprobe.get("cues") or {}).items()
        }
        view = {
            "image": pano.id,
            "hdr": pano.hdr,
            "photo": photo,
            "cues": cues,
            "residual_deg": aprobe.get("residual_deg"),
        }
        flags = _flags(aprobe, pixel=False)
        if photo.get("outline") is None:
            flags.append("no photo intrinsics")
        return Item(
            "heading", key, scene_id, probe_id, label, view, {"yaw_deg": yaw} if yaw is not None else None, flags
        )

    # -- access ------------------------------------------------------------------------------
    def item(self, kind: str, key: str) -> Item:
        try:
            return self.items[kind][key]
        except KeyError:
            raise KeyError(f"{kind} {key}") from None
