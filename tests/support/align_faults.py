"""Faults injected into a copy of an ingested campaign, for the align tests and benchmark.

Each function takes a campaign directory (a scratch copy: never the original) and a scene id,
changes what a field team or a camera could get wrong, and returns what it changed. The checks
live in the callers; nothing here reads the truth.

- :func:`occlude_sun`: the sun frame of one capture loses its sun (a tree in front of it).
- :func:`shift_clock`: every shot of the scene says a time ``hours`` later (camera clocks off).
- :func:`move_gps`: the photo's GPS says another place.
- :func:`rotate_heading`: one capture's compass heading is off by ``deg`` (the probe turned
  90° after the heading was taken, or the metadata of another shot).
- :func:`remove_texture`: one capture's HDR panorama is blurred flat (features fail there).
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import cv2
import numpy as np

from solidkit.envmap.io import read_exr, read_ldr, write_exr, write_ldr


def _manifest(campaign: Path) -> dict:
    return json.loads((campaign / "manifest.json").read_text())


def _save(campaign: Path, data: dict) -> None:
    path = campaign / "manifest.json"
    path.chmod(0o644)
    path.write_text(json.dumps(data, indent=1))


def _product(data: dict, scene: str, probe: str, kind: str) -> dict:
    return next(p for p in data["products"] if p["scene"] == scene and p["probe"] == probe and p["kind"] == kind)


def _writable(path: Path) -> Path:
    if path.exists():
        path.chmod(0o644)
    return path


def occlude_sun(campaign: Path, scene: str, probe: str) -> str:
    """Paint the saturated blobs of ``probe``'s sun frame with the dark sky around them."""
    data = _manifest(campaign)
    p = _product(data, scene, probe, "sun_frame")
    path = campaign / p["path"]
    img = read_ldr(path)
    sat = img.min(axis=2) >= 0.5
    sat = cv2.dilate(sat.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    img[sat] = np.median(img[~sat], axis=0)
    write_ldr(_writable(path), img)
    return f"{scene}/{probe}: sun painted out of {p['path']}"


def shift_clock(campaign: Path, scene: str, hours: float) -> str:
    data = _manifest(campaign)
    shas = set()
    for sc in data["scenes"]:
        if sc["id"] == scene:
            shas |= set(sc["photos"]) | {s for pr in sc["probes"] for s in pr["shots"]}
    for sh in data["shots"]:
        t = sh["metadata"].get("datetime_original")
        if sh["sha256"] in shas and t:
            sh["metadata"]["datetime_original"] = (dt.datetime.fromisoformat(t) + dt.timedelta(hours=hours)).isoformat()
    _save(campaign, data)
    return f"{scene}: every shot {hours:+g} h"


def move_gps(campaign: Path, scene: str, dlat: float) -> str:
    data = _manifest(campaign)
    photos = next(sc for sc in data["scenes"] if sc["id"] == scene)["photos"]
    for sh in data["shots"]:
        if sh["sha256"] in photos and sh["metadata"].get("gps"):
            g = sh["metadata"]["gps"]
            g["lat_deg"] = float(np.clip(g["lat_deg"] + dlat, -89.0, 89.0))
    _save(campaign, data)
    return f"{scene}: photo GPS latitude {dlat:+g} deg"


def rotate_heading(campaign: Path, scene: str, probe: str, deg: float) -> str:
    data = _manifest(campaign)
    shas = {
        s for sc in data["scenes"] if sc["id"] == scene for pr in sc["probes"] if pr["id"] == probe for s in pr["shots"]
    }
    for sh in data["shots"]:
        if sh["sha256"] in shas and sh["metadata"].get("heading_deg") is not None:
            sh["metadata"]["heading_deg"] = (sh["metadata"]["heading_deg"] + deg) % 360.0
    _save(campaign, data)
    return f"{scene}/{probe}: compass heading {deg:+g} deg"


def remove_texture(campaign: Path, scene: str, probe: str) -> str:
    data = _manifest(campaign)
    p = _product(data, scene, probe, "hdr")
    path = campaign / p["path"]
    img, meta = read_exr(path)
    flat = cv2.GaussianBlur(img, (0, 0), sigmaX=img.shape[0] / 20)
    write_exr(_writable(path), flat.astype(np.float32), meta if isinstance(meta, dict) else None)
    return f"{scene}/{probe}: HDR panorama blurred flat"


def move_probe_pixel(campaign: Path, scene: str, probe: str, dx: float, dy: float) -> str:
    data = _manifest(campaign)
    for sc in data["scenes"]:
        if sc["id"] == scene:
            for pr in sc["probes"]:
                if pr["id"] == probe and pr.get("photo_pixel") is not None:
                    pr["photo_pixel"] = [float(pr["photo_pixel"][0]) + dx, float(pr["photo_pixel"][1]) + dy]
    _save(campaign, data)
    return f"{scene}/{probe}: marked pixel moved by ({dx:+.0f}, {dy:+.0f}) px"
