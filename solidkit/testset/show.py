"""``solidkit testset show OUT``: a contact sheet per scene (PNG) and an HTML index to review a test set.

Each sheet shows the photo with its numbered probe pixels, the low-exposure sun panorama, the
camera-position capture and every aligned probe (256x128 LDR, shown at 2x) with the photo's
field of view outlined (its border rays ``R_cam K⁻¹ (x, y, 1)`` in the panorama frame,
conventions §1-4) and the sun marked (cross and circle of its uncertainty). Flags are printed
in red (a colour no probe is drawn in), each line saying what it belongs to: the scene, its sun,
the camera position, or probe ``n`` (:func:`flag_owners`). Probe pixels are the model-size photo's
(320x240), named as such. The HTML page lists every scene's numbers next to its sheet.
"""

from __future__ import annotations

import html
import math
import os
import textwrap
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from solidkit.envmap.coords import coords_from_angles, coords_from_direction, rotation_from_ypr
from solidkit.envmap.io import imread
from solidkit.envmap.perspective import rays_through_pixels, scale_pixel_coordinates
from solidkit.errors import InputError
from solidkit.fsutil import atomic_path, atomic_write_text
from solidkit.testset.build import load_testset
from solidkit.testset.schema import Scene, TestSet

__all__ = ["fov_outline", "flag_owners", "probe_title", "scene_sheet", "show_testset"]

PANO_SCALE = 2  # 256x128 probes drawn at 512x256
PHOTO_W = 640
SUN_COLOUR = (0, 215, 255)  # BGR: amber
FOV_COLOUR = (255, 255, 0)  # cyan
FLAG_COLOUR = (80, 80, 255)  # BGR: red, for flags only
PROBE_COLOURS = [  # BGR; none of them red (the flags' colour)
    (219, 152, 52),
    (113, 204, 46),
    (15, 196, 241),
    (182, 89, 155),
    (250, 206, 135),
    (156, 188, 26),
    (160, 160, 160),
    (94, 73, 52),
]
FONT = cv2.FONT_HERSHEY_SIMPLEX


def fov_outline(
    K: np.ndarray, size: tuple[int, int], pitch_deg: float, roll_deg: float, height: int, samples: int = 64
) -> list[np.ndarray]:
    """The photo's border as polylines in an equirect image of ``height`` (pixel coordinates).

    Border pixels ``(x, y)`` -> rays ``R K⁻¹ (x, y, 1)`` with ``R = R(0, pitch, roll)`` -> continuous
    equirect coordinates minus 0.5 (OpenCV drawing coordinates). The polyline is split where it
    crosses the ±180° seam.
    """
    w, h = size
    t = np.linspace(0.0, 1.0, samples, endpoint=False)
    xs = np.concatenate([t * (w - 1), np.full_like(t, w - 1), (1 - t) * (w - 1), np.zeros_like(t)]) - 0.0
    ys = np.concatenate([np.zeros_like(t), t * (h - 1), np.full_like(t, h - 1), (1 - t) * (h - 1)])
    # the outer edges of the border pixels
    xs = np.where(xs <= 0, -0.5, np.where(xs >= w - 1, w - 0.5, xs))
    ys = np.where(ys <= 0, -0.5, np.where(ys >= h - 1, h - 0.5, ys))
    rays = rays_through_pixels(K, xs, ys)
    R = np.asarray(rotation_from_ypr(0.0, math.radians(pitch_deg), math.radians(roll_deg)), np.float64)
    u, v = coords_from_direction(rays @ R.T, height)
    pts = np.stack([np.asarray(u) - 0.5, np.asarray(v) - 0.5], -1)
    pts = np.concatenate([pts, pts[:1]])
    lines, start = [], 0
    for i in range(1, len(pts)):
        if abs(pts[i, 0] - pts[i - 1, 0]) > height:  # wrapped around the seam
            lines.append(pts[start:i])
            start = i
    lines.append(pts[start:])
    return [ln for ln in lines if len(ln) > 1]


def _sun_px(az_deg: float, el_deg: float, height: int) -> tuple[float, float]:
    """OpenCV drawing coordinates (pixel centres at integers) of a direction given in degrees."""
    u, v = coords_from_angles(math.radians(az_deg), math.radians(el_deg), height)
    return float(u) - 0.5, float(v) - 0.5


def _label(img: np.ndarray, text: str, org: tuple[int, int], colour=(255, 255, 255), scale: float = 0.5) -> None:
    cv2.putText(img, text, org, FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, FONT, scale, colour, 1, cv2.LINE_AA)


def _pano_panel(img: np.ndarray, scene: Scene, title: str, colour=(255, 255, 255), width: int = 512) -> np.ndarray:
    h = width // 2
    pano = cv2.resize(
        img[..., :3] if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR),
        (width, h),
        interpolation=cv2.INTER_AREA if img.shape[1] > width else cv2.INTER_NEAREST,
    )
    shift = 4  # sub-pixel drawing
    for line in fov_outline(np.asarray(scene.K), scene.photo_size, scene.pitch_deg, scene.roll_deg, h):
        cv2.polylines(pano, [np.round(line * (1 << shift)).astype(np.int32)], False, FOV_COLOUR, 1, cv2.LINE_AA, shift)
    if scene.sun.found:
        assert scene.sun.azimuth_deg is not None and scene.sun.elevation_deg is not None  # a found sun has both
        u, v = _sun_px(scene.sun.azimuth_deg, scene.sun.elevation_deg, h)
        r = max(4.0, (scene.sun.uncertainty_deg or 0.0) * h / 180.0)
        c = (int(round(u)), int(round(v)))
        cv2.circle(pano, c, int(round(r)), SUN_COLOUR, 1, cv2.LINE_AA)
        cv2.drawMarker(pano, c, SUN_COLOUR, cv2.MARKER_CROSS, 14, 1, cv2.LINE_AA)
    bar = np.zeros((22, width, 3), np.uint8)
    _label(bar, title, (4, 16), colour)
    return np.vstack([bar, pano])


def flag_owners(scene: Scene) -> list[tuple[str, list[str]]]:
    """Every flag of a scene with what it belongs to, in the sheet's order: ``("scene", ...)``, ``("sun", ...)``,
    ``("camera <id>", ...)`` (the camera position's alignment), then ``("<n> <probe id>", ...)`` numbered as on
    the photo; owners without a flag are left out."""
    owners = [("scene", scene.flags), ("sun", scene.sun.flags)]
    if scene.camera is not None:
        owners.append((f"camera {scene.camera.id}", scene.camera.alignment.flags))
    owners += [(f"{k + 1} {p.id}", p.flags) for k, p in enumerate(scene.probes)]
    return [(owner, sorted(set(flags))) for owner, flags in owners if flags]


def probe_title(scene: Scene, k: int) -> str:
    """The title of probe ``k``'s panel: its number and id, its pixel in the model-size photo (named as such: the
    align report's pixels are full-resolution), where the pixel came from, its yaw and residual (degrees)."""
    p = scene.probes[k]
    res = p.alignment.residual_deg
    return (
        f"{k + 1}: {p.id} at ({p.pixel[0]:.0f},{p.pixel[1]:.0f}) of {scene.photo_size[0]}x{scene.photo_size[1]}"
        f" ({p.pixel_source}), yaw {p.alignment.yaw_deg:.1f}"
        + (f" res {res:.2f}" if res is not None else "")
        + (" HDR" if p.hdr else "")
    )


def scene_sheet(root: Path, scene: Scene) -> np.ndarray:
    """The contact sheet of one scene, BGR uint8."""
    photo = imread(root / scene.photo_full)
    photo = photo if photo.ndim == 3 else cv2.cvtColor(photo, cv2.COLOR_GRAY2BGR)
    W, H = scene.photo_full_size
    s = PHOTO_W / W
    ph = cv2.resize(photo[..., :3], (PHOTO_W, int(round(H * s))), interpolation=cv2.INTER_AREA)
    x0, y0, cw, chh = scene.crop_box
    cv2.rectangle(ph, (int(x0 * s), int(y0 * s)), (int((x0 + cw) * s) - 1, int((y0 + chh) * s) - 1), FOV_COLOUR, 1)
    for k, p in enumerate(scene.probes):
        col = PROBE_COLOURS[k % len(PROBE_COLOURS)]
        c = (
            int(round(scale_pixel_coordinates(p.pixel_full[0], s))),
            int(round(scale_pixel_coordinates(p.pixel_full[1], s))),
        )
        cv2.circle(ph, c, 7, col, 2, cv2.LINE_AA)
        _label(ph, str(k + 1), (c[0] + 9, c[1] - 6), col, 0.6)
    sun = scene.sun
    sun_txt = (
        f"sun az {sun.azimuth_deg:.1f} el {sun.elevation_deg:.1f} +-{sun.uncertainty_deg or 0:.1f} deg ({sun.source})"
        if sun.found
        else f"no sun ({sun.source})"
    )
    head = np.zeros((44, PHOTO_W, 3), np.uint8)
    _label(
        head,
        f"{scene.id}: {len(scene.probes)} probes, pitch {scene.pitch_deg:.1f} roll {scene.roll_deg:.1f} deg",
        (4, 17),
    )
    _label(head, sun_txt, (4, 37), SUN_COLOUR)
    left = [head, ph]
    lines = [ln for owner, flags in flag_owners(scene) for ln in textwrap.wrap(f"{owner}: " + "; ".join(flags), 100)]
    if lines:
        bar = np.zeros((20 * len(lines) + 6, PHOTO_W, 3), np.uint8)
        for k, line in enumerate(lines):
            _label(bar, line, (4, 16 + 20 * k), FLAG_COLOUR, 0.45)
        left.append(bar)
    panels = []
    if sun.panorama:
        panels.append(
            _pano_panel(
                imread(root / sun.panorama), scene, f"sun panorama ({sun.panorama_capture}, low exposure)", SUN_COLOUR
            )
        )
    if scene.camera is not None:
        panels.append(
            _pano_panel(imread(root / scene.camera.images.ldr), scene, f"camera position ({scene.camera.id})")
        )
    for k, p in enumerate(scene.probes):
        panels.append(
            _pano_panel(imread(root / p.ldr), scene, probe_title(scene, k), PROBE_COLOURS[k % len(PROBE_COLOURS)])
        )
    left_img = np.vstack(left)
    cols = 2
    rows = (
        [
            np.hstack(panels[i : i + cols] + [np.zeros_like(panels[0])] * (cols - len(panels[i : i + cols])))
            for i in range(0, len(panels), cols)
        ]
        if panels
        else [np.zeros((1, 1024, 3), np.uint8)]
    )
    right = np.vstack(rows)
    height = max(left_img.shape[0], right.shape[0])
    pad = lambda a: np.vstack([a, np.zeros((height - a.shape[0], a.shape[1], 3), np.uint8)])  # noqa: E731
    return np.hstack([pad(left_img), np.zeros((height, 6, 3), np.uint8), pad(right)])


def _html(ts: TestSet, sheets: dict[str, str]) -> str:
    e = html.escape
    rows = []
    for s in ts.scenes:
        sun = s.sun
        sun_txt = (
            f"{sun.azimuth_deg:.2f}, {sun.elevation_deg:.2f} ± {sun.uncertainty_deg or 0:.2f}°"
            if sun.found
            else "no sun"
        )
        probes = "".join(
            f"<tr><td>{k + 1}</td><td>{e(p.id)}</td><td>{p.pixel[0]:.1f}, {p.pixel[1]:.1f}</td>"
            f"<td>{e(p.pixel_source)}</td><td>{p.alignment.yaw_deg:.2f}</td>"
            f"<td>{'' if p.alignment.residual_deg is None else f'{p.alignment.residual_deg:.2f}'}</td>"
            f"<td>{e(p.alignment.source)}</td><td>{'yes' if p.hdr else 'no'}</td>"
            f"<td>{100 * p.images.saturated_fraction:.2f} %</td>"
            f"<td class=flag>{e(', '.join(p.flags))}</td></tr>"
            for k, p in enumerate(s.probes)
        )
        rows.append(
            f"<section id='{e(s.id)}'><h2>{e(s.id)}</h2>"
            f"<p>sun (photo panorama frame): <b>{e(sun_txt)}</b> — {e(sun.source)}"
            f"{' by ' + e(sun.annotator) if sun.annotator else ''}; pitch {s.pitch_deg:.2f}°, roll {s.roll_deg:.2f}°; "
            f"K from {e(s.K_source)}; photo {s.photo_full_size[0]}×{s.photo_full_size[1]}</p>"
            + "".join(
                f"<p class=flag>{e(owner)} flags: {e(', '.join(flags))}</p>"
                for owner, flags in flag_owners(s)
                if owner in ("scene", "sun") or owner.startswith("camera ")
            )
            + "<table><tr><th>#</th><th>probe</th><th>pixel (320×240)</th><th>pixel from</th><th>yaw °</th>"
            "<th>residual °</th><th>rotation from</th><th>HDR</th><th>clipped (solid angle)</th><th>flags</th></tr>"
            f"{probes}</table><img src='{e(sheets[s.id])}' alt='contact sheet of {e(s.id)}'></section>"
        )
    n_probes = sum(len(s.probes) for s in ts.scenes)
    return (
        "<!doctype html><html lang=en><head><meta charset=utf-8><title>test set "
        f"{e(ts.dataset_version)}</title><style>body{{font-family:sans-serif;margin:1em 2em}}"
        "table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%}"
        "img{max-width:100%}.flag{color:#c00}</style></head><body>"
        f"<h1>Test set {e(ts.dataset_version)}</h1><p>{len(ts.scenes)} scenes, {n_probes} probes; campaign "
        f"{e(ts.inputs.campaign)}; schema v{ts.version}; solidkit {e(ts.solidkit_version)}. Cyan: the photo's field of "
        "view; amber: the sun (circle: its uncertainty).</p>"
        + "<nav>"
        + " · ".join(f"<a href='#{e(s.id)}'>{e(s.id)}</a>" for s in ts.scenes)
        + "</nav>"
        + "".join(rows)
        + "</body></html>\n"
    )


def show_testset(root: str | os.PathLike, out: str | os.PathLike, *, log: Callable[[str], None] | None = None) -> Path:
    """Write ``out/<scene>.png`` per scene and ``out/index.html``; returns the HTML path."""
    root, out = Path(root), Path(out)
    ts = load_testset(root)
    if out.resolve() == root.resolve() or root.resolve() in out.resolve().parents:
        raise InputError(f"{out}: write the contact sheets outside the test set (its files are checksummed)")
    out.mkdir(parents=True, exist_ok=True)
    sheets = {}
    for s in ts.scenes:
        name = f"{s.id}.png"
        with atomic_path(out / name) as tmp:
            if not cv2.imwrite(str(tmp), scene_sheet(root, s)):
                raise InputError(f"{out / name}: cannot write PNG")
        sheets[s.id] = name
        if log:
            log(f"{out / name}")
    atomic_write_text(out / "index.html", _html(ts, sheets))
    return out / "index.html"
