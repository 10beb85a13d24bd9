"""A tiny campaign for the labeling app's tests, drawn with solidkit's own conventions.

Scene ``s1``: a 640x480 photo with a red dot at :data:`PHOTO_DOT` (full-res pixel) and three
Theta positions ``cam`` (camera position), ``p1``, ``p2``. Each position's sun frame is a dark
1024x512 equirect panorama with one coloured disk at a known direction (:data:`SUN_DOTS`);
``p1`` also has an HDR product with a red disk at azimuth :data:`HEADING_DOT_AZ` (level frame)
and the alignment (a C3-shaped dict) gives ``p1`` the yaw that puts that disk at the photo's
centre: ``yaw = -HEADING_DOT_AZ`` (d_P = R_y(yaw) d_L).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from solidkit.capture.manifest import Manifest, Probe, Product, Scene, Shot, save_manifest
from solidkit.envmap.coords import angular_distance, direction_from_angles, direction_grid, rotation_from_ypr
from solidkit.envmap.io import read_exr, srgb_encode, write_exr
from solidkit.envmap.perspective import perspective_crop
from solidkit.envmap.resample import rotate
from solidkit.envmap.sun import detect_sun

CITY = Path(__file__).resolve().parents[2] / "solidkit" / "assets" / "hdr_panoramas" / "city.exr"
CITY_YAWS = {"cam": 0.0, "p1": -50.0}  # heading of each capture (level frame -> photo panorama frame)
CITY_PIXEL = [350.0, 420.0]

PANO_H = 512
PHOTO_SIZE = (640, 480)
PHOTO_DOT = (400.0, 300.0)
FX = 500.0
# (azimuth_deg, elevation_deg, BGR colour) per position: one at negative azimuth, one high
SUN_DOTS = {
    "cam": (-120.0, 35.0, (255, 80, 40)),
    "p1": (40.0, 25.0, (40, 40, 255)),
    "p2": (150.0, 62.0, (40, 255, 40)),
}
HEADING_DOT_AZ = 30.0


def disk(image: np.ndarray, az_deg: float, el_deg: float, radius_deg: float, colour) -> None:
    """Paint the pixels within ``radius_deg`` of a direction (conventions §3) in place."""
    h = image.shape[0]
    d = np.asarray(direction_from_angles(math.radians(az_deg), math.radians(el_deg)))
    dist = angular_distance(direction_grid(h), np.broadcast_to(d, (h, 2 * h, 3)))
    image[dist < math.radians(radius_deg)] = colour


def make_campaign(root: Path, *, with_alignment: bool = True, with_city: bool = True) -> tuple[Path, dict | None]:
    """Write the campaign under ``root``; return it and its alignment dict (or None).

    ``with_city``: also the realistic scene ``city`` (from the shipped CC0 panorama).
    """
    root.mkdir(parents=True, exist_ok=True)
    (root / "originals").mkdir(exist_ok=True)
    photo = np.full((PHOTO_SIZE[1], PHOTO_SIZE[0], 3), (90, 110, 120), np.uint8)
    cv2.circle(photo, (int(PHOTO_DOT[0]), int(PHOTO_DOT[1])), 4, (0, 0, 255), -1)
    cv2.imwrite(str(root / "originals" / "photo.jpg"), photo, [cv2.IMWRITE_JPEG_QUALITY, 95])
    shots = [Shot(sha256="a" * 64, original="originals/photo.jpg", size=1, file_format="jpeg", sources=[],
                  metadata={"path": "photo.jpg", "width": PHOTO_SIZE[0], "height": PHOTO_SIZE[1]}, kind="photo",
                  scene="s1")]  # fmt: skip
    products, probes = [], []
    for pid, (az, el, colour) in SUN_DOTS.items():
        pano = np.full((PANO_H, 2 * PANO_H, 3), 12, np.uint8)
        disk(pano, az, el, 2.0, colour)
        rel = f"products/s1/{pid}/sun.png"
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / rel), pano)
        products.append(
            Product(id=f"s1/{pid}/sun", kind="sun_frame", scene="s1", probe=pid, inputs=[], path=rel, layout="equirect")
        )
        probes.append(Probe(id=pid, shots=[], role="camera" if pid == "cam" else "probe"))
    hdr = np.full((PANO_H, 2 * PANO_H, 3), 0.2, np.float32)
    hdr[PANO_H // 2 :] = 0.05  # ground darker than sky
    disk(hdr, HEADING_DOT_AZ, 0.0, 3.0, (2.0, 0.0, 0.0))  # RGB: red
    write_exr(root / "products/s1/p1/hdr-b01.exr", hdr)
    products.append(
        Product(
            id="s1/p1/hdr-b01",
            kind="hdr",
            scene="s1",
            probe="p1",
            inputs=[],
            path="products/s1/p1/hdr-b01.exr",
            layout="equirect",
        )
    )
    scene = Scene(id="s1", grouping="folder", photos=["a" * 64], photo="a" * 64, camera_probe="cam", probes=probes)
    city, city_align = _city(root, shots, products) if with_city else (None, None)
    scenes = [scene, city] if with_city else [scene]
    save_manifest(root, Manifest(shots=shots, scenes=scenes, products=products, conventions_version=1))
    if not with_alignment:
        return root, None
    K = [[FX, 0.0, (PHOTO_SIZE[0] - 1) / 2], [0.0, FX, (PHOTO_SIZE[1] - 1) / 2], [0.0, 0.0, 1.0]]
    az, el, _ = SUN_DOTS["p1"]
    alignment = {
        "scenes": [{
            "id": "s1", "camera_probe": "cam",
            "photo": {"path": "originals/photo.jpg", "sha256": "a" * 64, "size": list(PHOTO_SIZE), "K_full": K,
                      "K_source": "test", "pitch_deg": 0.0, "roll_deg": 0.0},
            "sun": {"found": True, "captures": [
                {"probe": "p1", "found": True, "azimuth_deg": az, "elevation_deg": el, "uncertainty_deg": 0.4,
                 "candidates": [
                     {"azimuth_deg": az, "elevation_deg": el, "size_deg": 1.0, "chosen": True, "reasons": []},
                     {"azimuth_deg": -60.0, "elevation_deg": 10.0, "size_deg": 0.6, "chosen": False,
                      "reasons": ["specular reflection: below the ephemeris by 15 deg"]},
                 ], "flags": []},
                {"probe": "p2", "found": False, "reason": "no saturated blob", "candidates": [], "flags": ["no_sun"]},
            ]},
            "probes": [
                {"id": "p1", "role": "probe", "pixel_full": [402.0, 297.0], "pixel_source": "field_notes",
                 "yaw_deg": -HEADING_DOT_AZ, "residual_deg": 0.3,
                 "cues": {"sun": {"yaw_deg": -HEADING_DOT_AZ, "weight": 1.0, "ok": True}}, "flags": []},
                {"id": "p2", "role": "probe", "pixel_full": None, "yaw_deg": None,
                 "flags": ["low_confidence", "pixel_disagrees: the marked pixel is 40 px from the geometry's"]},
            ],
        }] + ([city_align] if with_city else [])
    }  # fmt: skip
    return root, alignment


def _ldr8(linear: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.round(srgb_encode(linear) * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)


def _city(root: Path, shots: list, products: list) -> tuple[Scene, dict]:
    """Scene ``city`` from the shipped CC0 panorama: a photo cut from it (pinhole, fx 500, looking
    forward) and two captures whose level frames are the photo's panorama turned by CITY_YAWS."""
    pano, _ = read_exr(CITY)
    photo = perspective_crop(pano, rotation_from_ypr(0.0, math.radians(4.0), 0.0), PHOTO_SIZE,
                             K=np.array([[FX, 0, 319.5], [0, FX, 239.5], [0, 0, 1.0]]))  # fmt: skip
    cv2.imwrite(str(root / "originals" / "city.jpg"), _ldr8(photo * 1.2), [cv2.IMWRITE_JPEG_QUALITY, 92])
    shots.append(Shot(sha256="b" * 64, original="originals/city.jpg", size=1, file_format="jpeg", sources=[],
                      metadata={"path": "city.jpg", "width": PHOTO_SIZE[0], "height": PHOTO_SIZE[1]}, kind="photo",
                      scene="city"))  # fmt: skip
    probes, captures, aprobes = [], [], []
    for pid, yaw in CITY_YAWS.items():
        level = rotate(pano, rotation_from_ypr(math.radians(-yaw), 0.0, 0.0))  # d_P = R_y(yaw) d_L
        (root / f"products/city/{pid}").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / f"products/city/{pid}/sun.png"), _ldr8(level / 3000.0))  # low exposure: only the sun
        write_exr(root / f"products/city/{pid}/hdr-b01.exr", level.astype(np.float32))
        products.append(Product(id=f"city/{pid}/sun", kind="sun_frame", scene="city", probe=pid, inputs=[],
                                path=f"products/city/{pid}/sun.png", layout="equirect"))  # fmt: skip
        products.append(Product(id=f"city/{pid}/hdr-b01", kind="hdr", scene="city", probe=pid, inputs=[],
                                path=f"products/city/{pid}/hdr-b01.exr", layout="equirect"))  # fmt: skip
        probes.append(Probe(id=pid, shots=[], role="camera" if pid == "cam" else "probe"))
        sun = detect_sun(level)
        captures.append({"probe": pid, "found": True, "azimuth_deg": sun.azimuth_deg,
                         "elevation_deg": sun.elevation_deg, "uncertainty_deg": 0.3, "flags": [], "candidates": [
                             {"azimuth_deg": sun.azimuth_deg, "elevation_deg": sun.elevation_deg, "size_deg": 1.2,
                              "chosen": True, "reasons": []},
                             {"azimuth_deg": sun.azimuth_deg + 95.0, "elevation_deg": 4.0, "size_deg": 0.5,
                              "chosen": False,
                              "reasons": ["glint on a facade: 30 deg below the ephemeris"]}]})  # fmt: skip
        aprobes.append({"id": pid, "role": "camera" if pid == "cam" else "probe", "yaw_deg": yaw, "residual_deg": 0.4,
                        "pixel_full": CITY_PIXEL if pid == "p1" else None,
                        "pixel_source": "field_notes" if pid == "p1" else None,
                        "cues": {"sun": {"yaw_deg": yaw + 0.2, "weight": 0.6, "ok": True},
                                 "features": {"yaw_deg": yaw - 0.3, "weight": 0.4, "ok": True}},
                        "flags": []})  # fmt: skip
    scene = Scene(id="city", grouping="folder", photos=["b" * 64], photo="b" * 64, camera_probe="cam", probes=probes)
    K = [[FX, 0.0, 319.5], [0.0, FX, 239.5], [0.0, 0.0, 1.0]]
    align = {"id": "city", "camera_probe": "cam", "sun": {"found": True, "captures": captures}, "probes": aprobes,
             "photo": {"path": "originals/city.jpg", "sha256": "b" * 64, "size": list(PHOTO_SIZE), "K_full": K,
                       "K_source": "test", "pitch_deg": 4.0, "roll_deg": 0.0}}  # fmt: skip
    return scene, align
