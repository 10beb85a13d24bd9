"""The alignment report: ``CAMPAIGN/align/report.md``, ``report.html`` and ``report/<scene>.png``.

Per scene: a table of the captures (yaw, the cues and their residuals, sun, pixel, flags) and a
picture: the photo with the probe pixels (marked, and where the geometry puts them) and, for
every capture, its aligned LDR probe with the photo's field of view outlined (the photo's
border rays through ``K`` and its pitch/roll, conventions §1-2), the scene's sun (yellow
circle), this capture's own sun (green cross) and its rejected candidates (red x).
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import cv2
import numpy as np

from solidkit.align.features import rays_from_pixels
from solidkit.align.schema import CampaignAlignment, CaptureSun, ProbeAlignment, SceneAlignment, wrap_deg
from solidkit.capture.manifest import Manifest
from solidkit.envmap.coords import coords_from_direction, direction_from_angles, rotation_from_ypr
from solidkit.envmap.io import imread, write_ldr
from solidkit.envmap.perspective import scale_pixel_coordinates
from solidkit.flags import flag_codes
from solidkit.fsutil import atomic_write_text

__all__ = ["write_report", "scene_picture", "capture_flag_codes"]

PANEL_H = 256
_YELLOW, _GREEN, _RED, _CYAN, _WHITE = (255, 220, 0), (0, 230, 0), (255, 40, 40), (0, 220, 255), (255, 255, 255)
_FLAGGED = (255, 180, 80)


def capture_flag_codes(pa: ProbeAlignment, cs: CaptureSun | None) -> list[str]:
    """The flag codes of a capture as its panel's title lists them: its alignment's, then its sun's (a glint
    chosen as the sun is flagged there), each once."""
    return list(dict.fromkeys(flag_codes(pa.flags) + (flag_codes(cs.flags) if cs is not None else [])))


def _in_photo(pixel: list[float], s: float, shape: tuple[int, ...]) -> tuple[tuple[int, int], bool]:
    """A full-resolution photo pixel drawn at scale ``s`` in an image of ``shape``: its drawing point, clamped to
    4 px inside the border where it lies outside, and whether it lies inside."""
    x, y = (float(scale_pixel_coordinates(v, s)) for v in pixel)
    h, w = shape[:2]
    cx, cy = min(max(x, 4.0), w - 5.0), min(max(y, 4.0), h - 5.0)
    return (int(round(cx)), int(round(cy))), (cx, cy) == (x, y)


def _outside_arrow(
    img: np.ndarray, pixel: list[float], s: float, at: tuple[int, int], inside: bool, colour: tuple[int, int, int]
) -> None:
    """For a pixel outside the photo: an arrow from inside the border to where it is drawn, pointing toward it."""
    if inside:
        return
    x, y = (float(scale_pixel_coordinates(v, s)) for v in pixel)
    d = np.array([x - at[0], y - at[1]])
    d = d / max(float(np.linalg.norm(d)), 1e-9)
    tail = (int(round(at[0] - 22 * d[0])), int(round(at[1] - 22 * d[1])))
    cv2.arrowedLine(img, tail, at, colour, 2, cv2.LINE_AA, tipLength=0.4)


def _fov_outline(sa: SceneAlignment, height: int, n: int = 60) -> list[np.ndarray]:
    """Equirect polylines ``(k, 2)`` of the photo's border in the photo's panorama frame (split at the seam)."""
    p = sa.photo
    assert p is not None  # drawn only for a scene with a photo
    w, h = p.size
    K = np.asarray(p.K_full)
    t = np.linspace(0.0, 1.0, n)
    xs = np.concatenate([t * (w - 1), np.full(n, w - 1.0), (1 - t) * (w - 1), np.zeros(n)])
    ys = np.concatenate([np.zeros(n), t * (h - 1), np.full(n, h - 1.0), (1 - t) * (h - 1)])
    rays = rays_from_pixels(np.c_[xs, ys], K)
    R = np.asarray(rotation_from_ypr(0.0, math.radians(p.pitch_deg or 0.0), math.radians(p.roll_deg or 0.0)))
    d = rays @ R.T
    x, y = coords_from_direction(d / np.linalg.norm(d, axis=1, keepdims=True), height)
    pts = np.c_[x, y]
    cuts = np.nonzero(np.abs(np.diff(pts[:, 0])) > height)[0]
    return [seg for seg in np.split(pts, cuts + 1) if len(seg) > 1]


def _mark(img: np.ndarray, az_deg: float, el_deg: float, kind: str, colour: tuple[int, int, int]) -> None:
    h = img.shape[0]
    x, y = coords_from_direction(direction_from_angles(math.radians(az_deg), math.radians(el_deg)), h)
    c = (int(round(float(x) - 0.5)), int(round(float(y) - 0.5)))
    if kind == "circle":
        cv2.circle(img, c, 9, colour, 2, cv2.LINE_AA)
    elif kind == "cross":
        cv2.drawMarker(img, c, colour, cv2.MARKER_CROSS, 16, 2, cv2.LINE_AA)
    else:
        cv2.drawMarker(img, c, colour, cv2.MARKER_TILTED_CROSS, 10, 1, cv2.LINE_AA)


def _label(img: np.ndarray, text: str, colour: tuple[int, int, int] = _WHITE) -> None:
    cv2.rectangle(img, (0, 0), (img.shape[1], 18), (0, 0, 0), -1)
    cv2.putText(img, text, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, colour, 1, cv2.LINE_AA)


def scene_picture(campaign: Path, sa: SceneAlignment) -> np.ndarray:
    """RGB uint8 picture of one scene (module doc)."""
    panels = []
    width = 2 * PANEL_H
    if sa.photo is not None and (campaign / sa.photo.path).is_file():
        ph = cv2.cvtColor(imread(campaign / sa.photo.path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        s = width / ph.shape[1]
        ph = cv2.resize(ph, (width, int(round(ph.shape[0] * s))), interpolation=cv2.INTER_AREA)
        for pa in sa.probes:
            if pa.pixel_full is not None:
                c, inside = _in_photo(pa.pixel_full, s, ph.shape)
                cv2.circle(ph, c, 6, _CYAN, 2, cv2.LINE_AA)
                _outside_arrow(ph, pa.pixel_full, s, c, inside, _CYAN)
                cv2.putText(ph, pa.id, (c[0] + 8, c[1] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _CYAN, 1, cv2.LINE_AA)
            if pa.pixel_geometry is not None:
                g, inside = _in_photo(pa.pixel_geometry, s, ph.shape)
                cv2.drawMarker(ph, g, _YELLOW, cv2.MARKER_DIAMOND, 10, 1, cv2.LINE_AA)
                _outside_arrow(ph, pa.pixel_geometry, s, g, inside, _YELLOW)
        _label(ph, f"{sa.id}: photo (cyan: probe pixels, yellow: geometry; on the border, arrow out: outside)")
        panels.append(ph)
    suns = {c.probe: c for c in sa.sun.captures}
    for pa in sa.probes:
        path = pa.products.ldr_full
        if not path or not (campaign / path).is_file():
            continue
        img = cv2.cvtColor(imread(campaign / path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        img = np.ascontiguousarray(cv2.resize(img, (width, PANEL_H), interpolation=cv2.INTER_AREA))
        if sa.photo is not None:
            for seg in _fov_outline(sa, PANEL_H):
                cv2.polylines(img, [np.round(seg - 0.5).astype(np.int32)], False, _WHITE, 1, cv2.LINE_AA)
        if sa.sun.found and sa.sun.azimuth_deg is not None:
            assert sa.sun.elevation_deg is not None  # set with the azimuth
            _mark(img, sa.sun.azimuth_deg, sa.sun.elevation_deg, "circle", _YELLOW)
        cs = suns.get(pa.id)
        if cs is not None and pa.yaw_deg is not None:
            for cand in cs.candidates:
                if not cand.chosen:
                    _mark(img, wrap_deg(cand.azimuth_deg + pa.yaw_deg), cand.elevation_deg, "x", _RED)
            if cs.found:
                assert cs.azimuth_deg is not None and cs.elevation_deg is not None  # a found sun has both
                _mark(img, wrap_deg(cs.azimuth_deg + pa.yaw_deg), cs.elevation_deg, "cross", _GREEN)
        codes = capture_flag_codes(pa, cs)
        flags = ", ".join(codes)
        _label(
            img,
            f"{pa.id} ({pa.role}) yaw {pa.yaw_deg:+.2f} deg" + (f"  [{flags}]" if flags else ""),
            _WHITE if not codes else _FLAGGED,
        )
        panels.append(img)
    if not panels:
        blank = np.zeros((PANEL_H, width, 3), np.uint8)
        _label(blank, f"{sa.id}: nothing to show")
        panels.append(blank)
    return np.concatenate([np.pad(p, ((0, 4), (0, 0), (0, 0))) for p in panels], axis=0)


def _fmt(v: float | None, nd: int = 2) -> str:
    return "-" if v is None else f"{v:+.{nd}f}"


def _scene_rows(sa: SceneAlignment) -> list[list[str]]:
    suns = {c.probe: c for c in sa.sun.captures}
    rows = []
    for pa in sa.probes:
        cs = suns.get(pa.id)
        cues = "; ".join(
            f"{k} {_fmt(c.yaw_deg)}{'' if c.ok else ' (x)'}"
            + ("" if c.residual_deg is None else f" r{c.residual_deg:+.2f}")
            for k, c in sorted(pa.cues.items())
        )
        sun = (
            "-"
            if cs is None
            else (f"{cs.azimuth_deg:+.2f}/{cs.elevation_deg:.2f}" if cs.found else "none")
            + (f" ({sum(1 for k in cs.candidates if not k.chosen)} rejected)" if cs and cs.candidates else "")
        )
        px = "-" if pa.pixel_full is None else f"({pa.pixel_full[0]:.0f}, {pa.pixel_full[1]:.0f}) {pa.pixel_source}"
        flags = pa.flags + [f for f in (cs.flags if cs is not None else []) if f not in pa.flags]
        rows.append(
            [
                pa.id,
                pa.role,
                _fmt(pa.yaw_deg) + ("" if pa.yaw_source == "auto" else f" ({pa.yaw_source})"),
                _fmt(pa.residual_deg),
                cues,
                sun,
                px,
                "; ".join(flags) or "-",
            ]
        )
    return rows


_HEAD = [
    "capture",
    "role",
    "yaw (deg)",
    "residual",
    "cues (yaw, residual)",
    "sun az/el (level frame)",
    "pixel (full-resolution photo)",
    "flags (alignment; sun)",
]


def write_report(campaign: Path, manifest: Manifest, al: CampaignAlignment) -> Path:
    """Write the Markdown and HTML reports and one PNG per scene; returns the HTML path."""
    root = campaign / "align"
    md = [
        "# Alignment report\n",
        f"Campaign `{campaign}`; solidkit {al.solidkit_version}; conventions §8 "
        "(yaw: capture level frame -> photo panorama frame).\n",
    ]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>solidkit alignment report</title><style>"
        "body{font-family:sans-serif;margin:1.5em;max-width:1400px}table{border-collapse:collapse;font-size:13px}"
        "td,th{border:1px solid #ccc;padding:3px 6px;vertical-align:top}.flag{color:#b35900}img{max-width:100%}"
        "</style></head><body><h1>Alignment report</h1>",
        f"<p>Campaign <code>{html.escape(str(campaign))}</code>; solidkit {html.escape(al.solidkit_version)}. "
        "Yaw: capture level frame → photo panorama frame (conventions §8). Picture: white = the photo's field of view, "
        "yellow circle = the scene's sun, green cross = this capture's sun, red x = rejected candidates.</p>",
    ]
    n_flagged = sum(1 for sa in al.scenes for p in sa.probes if p.flags) + sum(
        1 for sa in al.scenes if sa.flags or sa.sun.flags
    )
    md.append(
        f"{len(al.scenes)} scenes, {sum(len(sa.probes) for sa in al.scenes)} captures, {n_flagged} flagged items.\n"
    )
    parts.append(
        f"<p>{len(al.scenes)} scenes, {sum(len(sa.probes) for sa in al.scenes)} captures, {n_flagged} flagged "
        "items.</p>"
    )
    for sa in al.scenes:
        png = Path("report") / f"{sa.id}.png"
        write_ldr(root / png, scene_picture(campaign, sa))
        s = sa.sun
        sun = (
            "no sun found"
            if not s.found
            else f"azimuth {_fmt(s.azimuth_deg)} deg, elevation {s.elevation_deg:.2f} deg in the photo frame"
            + ("" if s.world_azimuth_deg is None else f" (world azimuth {s.world_azimuth_deg:.2f} deg from north)")
            + f", ±{s.uncertainty_deg:.2f} deg from {s.n_captures} capture(s)"
        )
        eph = (
            ""
            if s.ephemeris is None
            else (
                f"; ephemeris {s.ephemeris.azimuth_deg:.2f}/{s.ephemeris.elevation_deg:.2f} deg at "
                f"{s.ephemeris.time_utc}"
            )
        )
        flags = sa.flags + s.flags
        md += [f"\n## {sa.id}\n", f"Sun: {sun}{eph}. {s.motion}\n"]
        if flags:
            md.append("Flags: " + "; ".join(flags) + "\n")
        md.append("| " + " | ".join(_HEAD) + " |\n|" + "---|" * len(_HEAD) + "\n")
        md += ["| " + " | ".join(c.replace("|", "/") for c in r) + " |\n" for r in _scene_rows(sa)]
        md.append(f"\n![{sa.id}]({(Path('report') / png.name).as_posix()})\n")
        parts.append(f"<h2>{html.escape(sa.id)}</h2><p>Sun: {html.escape(sun + eph)}. {html.escape(s.motion)}</p>")
        if flags:
            parts.append("<p class='flag'>Flags: " + html.escape("; ".join(flags)) + "</p>")
        parts.append("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in _HEAD) + "</tr>")
        for r in _scene_rows(sa):
            parts.append(
                "<tr>"
                + "".join(
                    f"<td{' class=flag' if i == 7 and c != '-' else ''}>{html.escape(c)}</td>" for i, c in enumerate(r)
                )
                + "</tr>"
            )
        parts.append(f"</table><p><img src='{png.as_posix()}' alt='{html.escape(sa.id)}'></p>")
    parts.append("</body></html>")
    atomic_write_text(root / "report.md", "".join(md))
    out = root / "report.html"
    atomic_write_text(out, "\n".join(parts))
    del manifest
    return out
