"""A small analytic campaign for the test-set tests: ingest-shaped manifest, align-shaped alignment.json.

The world is one distant HDR panorama in each scene's photo panorama frame ``P`` (sky gradient,
a sun disk, a textured ground, dark "buildings"): every capture sees the same environment, so
the truth of each aligned probe is ``P`` itself, the sun is known exactly, and the photo is a
pinhole view of ``P``. The aligned products are made the way align makes them: the capture's
level-frame panorama ``L_c = rotate(P, R_y(yaw_c)ᵀ)`` rotated back by ``R_y(yaw_c)``. Nothing
here reads a test set; it only writes campaign inputs.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import cv2
import numpy as np

from solidkit.align.schema import (
    CampaignAlignment,
    CaptureSun,
    Cue,
    Levelling,
    PhotoInfo,
    ProbeAlignment,
    ProbeProducts,
    SceneAlignment,
    SceneSun,
    body_to_pano,
    level_to_pano,
    save_alignment,
)
from solidkit.capture.manifest import Bracket, Manifest, Probe, Product, Scene, Shot
from solidkit.envmap import CONVENTIONS_VERSION
from solidkit.envmap.coords import direction_grid, rotation_from_ypr
from solidkit.envmap.io import srgb_encode, write_exr, write_ldr
from solidkit.envmap.perspective import intrinsics_from_fov, perspective_crop
from solidkit.envmap.resample import resize, rotate

PANO_H = 128  # full-resolution aligned products: 256x128 -> the 256x128 probe is a plain copy... use 2x
FULL_H = 256
PHOTO = (640, 480)
HFOV_DEG = 60.0


def world(sun_az_deg: float | None, sun_el_deg: float, height: int = FULL_H, seed: int = 0) -> np.ndarray:
    """An HDR environment ``(H, 2H, 3)`` in the photo's panorama frame (conventions §3)."""
    d = direction_grid(height)
    up = -d[..., 1]
    az = np.arctan2(d[..., 0], d[..., 2])
    sky = np.stack([0.35 + 0.3 * (1 - up), 0.55 + 0.25 * (1 - up), 1.0 + 0.0 * up], -1) * 2.0
    u, v = np.meshgrid(np.arange(2 * height), np.arange(height))
    checker = ((u // 8 + v // 8) % 2).astype(np.float32)
    ground = np.stack([0.30 + 0.1 * checker, 0.25 + 0.1 * checker, 0.2 + 0.05 * checker], -1)
    img = np.where(up[..., None] > 0, sky, ground)
    rng = np.random.default_rng(seed)
    for centre in rng.uniform(-math.pi, math.pi, 4):  # buildings: dark boxes with windows
        width, top = rng.uniform(0.3, 0.6), rng.uniform(0.25, 0.6)
        inside = (
            (np.abs(np.angle(np.exp(1j * (az - centre)))) < width / 2)
            & (up > 0)
            & (np.arcsin(np.clip(up, -1, 1)) < top)
        )
        windows = (((u // 5) % 3 == 0) & ((v // 5) % 3 == 0)).astype(np.float32)
        facade = np.stack([0.15 + 0.3 * windows, 0.12 + 0.3 * windows, 0.10 + 0.35 * windows], -1)
        img = np.where(inside[..., None], facade, img)
    if sun_az_deg is not None:
        s = np.array(
            [
                math.cos(math.radians(sun_el_deg)) * math.sin(math.radians(sun_az_deg)),
                -math.sin(math.radians(sun_el_deg)),
                math.cos(math.radians(sun_el_deg)) * math.cos(math.radians(sun_az_deg)),
            ]
        )
        img = np.where((d @ s > math.cos(math.radians(1.5)))[..., None], 5000.0, img)
    return img.astype(np.float32)


def _ldr(hdr: np.ndarray, scale: float) -> np.ndarray:
    return np.round(srgb_encode(np.clip(hdr * scale, 0, 1)) * 255).astype(np.uint8)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


SCENES = {
    # id: (sun azimuth in P, elevation, photo pitch, roll, probe pixels (full res), capture yaws)
    "sA": (
        35.0,
        40.0,
        -6.0,
        1.0,
        {"p01": (200.0, 420.0), "p02": (470.0, 395.0)},
        {"cam": -20.0, "p01": 70.0, "p02": -130.0},
    ),
    "sB": (None, 30.0, -3.0, -0.5, {"p01": (320.0, 430.0)}, {"cam": 10.0, "p01": 160.0}),
}


def make_campaign(root: Path, scenes: dict | None = None) -> dict:
    """Write the campaign under ``root``; returns its truth ``{scene: {...}}`` (kept apart from the files)."""
    scenes = SCENES if scenes is None else scenes
    root.mkdir(parents=True, exist_ok=True)
    shots, msc, products, sal, truth = [], [], [], [], {}
    K = intrinsics_from_fov(math.radians(HFOV_DEG), *PHOTO)
    for si, (sid, (saz, sel, pitch, roll, pixels, yaws)) in enumerate(sorted(scenes.items())):
        P = world(saz, sel, seed=si)
        R_cam = np.asarray(rotation_from_ypr(0.0, math.radians(pitch), math.radians(roll)))
        photo = perspective_crop(P, R_cam, PHOTO, K=K)
        ok, jpg = cv2.imencode(".jpg", _ldr(photo, 0.5)[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        data = jpg.tobytes()
        sha = _sha(data)
        rel = f"originals/{sha[:2]}/{sha}.jpg"
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
        shots.append(
            Shot(
                sha256=sha,
                original=rel,
                size=len(data),
                file_format="jpeg",
                sources=[],
                kind="photo",
                scene=sid,
                probe="photo",
                metadata={
                    "datetime_original": "2024-06-01T12:00:00",
                    "utc_offset": "+02:00",
                    "gps": {"lat_deg": 48.1, "lon_deg": 11.5, "alt_m": 520.0},
                    "make": "TEST",
                    "model": "Photo",
                    "exposure_time": 0.004,
                    "f_number": 2.8,
                    "iso": 100.0,
                    "focal_length_mm": 5.0,
                },
            )
        )
        probes_m, probes_a, caps = [], [], []
        for ci, (cid, yaw) in enumerate(sorted(yaws.items())):
            cp, cr = 1.5 * (ci - 1), -0.7 * ci  # the capture's levelling (irrelevant to the level frame)
            L = rotate(P, level_to_pano(yaw).T)  # level-frame panorama of this capture
            d = f"products/{sid}/{cid}"
            (root / d).mkdir(parents=True, exist_ok=True)
            write_exr(root / d / "hdr-b01.exr", L)
            write_ldr(root / d / "sun.png", _ldr(L, 0.002))
            cshots = []
            for k, t in enumerate((1 / 640, 1 / 160, 1 / 40, 1 / 25000)):
                s = _sha(f"{sid}{cid}{k}".encode())
                cshots.append(s)
                shots.append(
                    Shot(
                        sha256=s,
                        original=f"originals/{s[:2]}/{s}.jpg",
                        size=1,
                        file_format="jpeg",
                        sources=[],
                        kind="bracket_member" if k < 3 else "low_exposure",
                        scene=sid,
                        probe=cid,
                        metadata={
                            "datetime_original": f"2024-06-01T12:0{ci + 1}:0{k}",
                            "model": "RICOH THETA V",
                            "exposure_time": t,
                            "f_number": 2.0,
                            "iso": 100.0,
                            "pitch_deg": cp,
                            "roll_deg": cr,
                        },
                    )
                )
            probes_m.append(
                Probe(
                    id=cid,
                    shots=cshots,
                    brackets=[Bracket(id="b01", shots=cshots[:3], exposure_times=[1 / 640, 1 / 160, 1 / 40])],
                    sun_frame=cshots[3],
                )
            )
            products += [
                Product(
                    id=f"{sid}/{cid}/hdr-b01",
                    kind="hdr",
                    scene=sid,
                    probe=cid,
                    inputs=cshots[:3],
                    path=f"{d}/hdr-b01.exr",
                    layout="equirect",
                    exposure_time=1 / 640,
                    f_number=2.0,
                    iso=100.0,
                    stats={"profile": "theta-v"},
                ),
                Product(
                    id=f"{sid}/{cid}/sun",
                    kind="sun_frame",
                    scene=sid,
                    probe=cid,
                    inputs=cshots[3:],
                    path=f"{d}/sun.png",
                    layout="equirect",
                    exposure_time=1 / 25000,
                    f_number=2.0,
                    iso=100.0,
                ),
            ]
            # align's products: back to the photo frame
            A = rotate(L, level_to_pano(yaw))
            a = f"align/{sid}/{cid}"
            (root / a).mkdir(parents=True, exist_ok=True)
            ldr_full = _ldr(A, 0.5)
            write_ldr(root / a / "ldr_full.png", ldr_full)
            small = resize(A, PANO_H)
            write_ldr(root / a / "ldr_256.png", _ldr(small, 0.5))
            write_exr(root / a / "hdr_256.exr", small)
            write_exr(root / a / "hdr_full.exr", A)
            for name, img in (("saturation_256", _ldr(small, 0.5)), ("saturation_full", ldr_full)):
                cv2.imwrite(str(root / a / f"{name}.png"), ((img.max(-1) >= 250) * 255).astype(np.uint8))
            role = "camera" if cid == "cam" else "probe"
            probes_a.append(
                ProbeAlignment(
                    id=cid,
                    role=role,
                    pixel_full=list(pixels[cid]) if role == "probe" else None,
                    pixel_source="field_notes" if role == "probe" else None,
                    levelling=Levelling(pitch_deg=cp, roll_deg=cr, source="metadata"),
                    rotation=body_to_pano(yaw, cp, cr).tolist(),
                    yaw_deg=yaw,
                    yaw_source="auto",
                    residual_deg=0.3,
                    cues={
                        "sun": Cue(yaw_deg=yaw + 0.2, weight=1.0, ok=True),
                        "features": Cue(yaw_deg=yaw - 0.3, weight=2.0, ok=True),
                    },
                    products=ProbeProducts(
                        ldr_full=f"{a}/ldr_full.png",
                        ldr_256=f"{a}/ldr_256.png",
                        hdr_256=f"{a}/hdr_256.exr",
                        hdr_full=f"{a}/hdr_full.exr",
                        saturation_256=f"{a}/saturation_256.png",
                        saturation_full=f"{a}/saturation_full.png",
                    ),
                )
            )
            caps.append(
                CaptureSun(
                    probe=cid,
                    found=saz is not None,
                    azimuth_deg=None if saz is None else saz - yaw,
                    elevation_deg=None if saz is None else sel,
                    uncertainty_deg=0.5,
                )
            )
        msc.append(Scene(id=sid, grouping="folder", photos=[sha], probes=probes_m))
        sal.append(
            SceneAlignment(
                id=sid,
                photo=PhotoInfo(
                    path=rel,
                    sha256=sha,
                    size=list(PHOTO),
                    K_full=K.tolist(),
                    K_source="exif-35mm",
                    pitch_deg=pitch,
                    roll_deg=roll,
                    heading_deg=100.0,
                    pitch_roll_source="exif",
                ),
                camera_probe="cam",
                sun=SceneSun(
                    found=saz is not None,
                    azimuth_deg=saz,
                    elevation_deg=sel if saz is not None else None,
                    uncertainty_deg=0.6 if saz is not None else None,
                    n_captures=len(caps),
                    captures=caps,
                ),
                probes=probes_a,
            )
        )
        truth[sid] = {
            "panorama": P,
            "sun": None if saz is None else (saz, sel),
            "pixels": pixels,
            "K": K,
            "pitch": pitch,
            "roll": roll,
            "yaws": yaws,
        }
    manifest = Manifest(
        solidkit_version="test", conventions_version=CONVENTIONS_VERSION, shots=shots, scenes=msc, products=products
    )
    (root / "manifest.json").write_text(manifest.model_dump_json(indent=1) + "\n")
    msha = hashlib.sha256((root / "manifest.json").read_bytes()).hexdigest()
    save_alignment(CampaignAlignment(manifest_sha256=msha, scenes=sal), root)
    return truth


def edit_alignment(root: Path, edit) -> None:
    """Apply ``edit(dict)`` to ``align/alignment.json`` (tests of bad or changed alignments)."""
    p = root / "align" / "alignment.json"
    data = json.loads(p.read_text())
    edit(data)
    p.write_text(json.dumps(data, indent=1))
