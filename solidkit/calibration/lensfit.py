"""A lens profile for any dual-fisheye camera from one frame (``solidkit calibrate fisheye``).

Steps (each recorded in the result):

1. **Image circles** and their arrangement (side by side / stacked):
   :func:`solidkit.calibration.circles.find_image_circles`.
2. **Relative layout**: the back lens looks the other way (yaw 180°) with its circle turned by
   0, 90, 180 or 270° relative to the front's; the turn whose overlap agrees best (seam error of
   an equidistant start, half-field in 1° steps, on the frame reduced to ~64 px radius) is kept.
3. **Projection family and field of view**: for each family of :data:`FAMILIES`, ``r(theta) =
   k g(theta)`` with the scale ``k`` set so that the half-field ``theta_edge`` falls on the fitted
   circle (``r(theta_edge) = R``, per lens); ``theta_edge`` is scanned over
   [:data:`MIN_HALF_FOV_DEG`, :data:`MAX_HALF_FOV_DEG`] in 0.25° steps on the frame reduced to
   ~128 px radius, then in 0.05° steps within ±0.4° of the best at ~256 px,
   minimising the seam error (:func:`solidkit.calibration.seam.seam_error`, scale free, so
   candidates with overlap rings of different widths compare). The family with the lowest error
   wins the start; the field of view is ``2 theta_edge``. With refinement on, every family within
   15 % of the best start is refined and the lowest refined (or kept) seam error decides.

   ``g``: ``equidistant`` theta (``r = f theta``), ``equisolid`` ``2 sin(theta/2)``, ``theta``:
   Ricoh's design table of the Theta V/S lens unit (the ``theta-v`` profile's, up to 100°;
   continued linearly to 103°).
   Before that, the back lens' aim: yaw and pitch offsets from exactly opposite within
   ±:data:`MAX_BACK_OFFSET_DEG` in 2° steps (kept only when they lower the seam error by 3 %+).
4. **Which way is up** (:func:`solidkit.calibration.upright.estimate_upright`): the roll that makes
   the panorama upright goes into both lenses' rotations.
5. **Per-unit refinement** (:func:`solidkit.calibration.overlap.refine_overlap`), made robust:
   bounded (centres ±:data:`MAX_CENTER_FRAC` of the radius, scales ±3 %, back-lens rotation
   ±:data:`MAX_BACK_OFFSET_DEG` per axis: one frame pins the aim poorly), multi-start (the back lens turned ±1°
   about x and y, on the coarsest level, the best continued coarse to fine), and **refused** when the seam error
   (:func:`solidkit.calibration.seam.seam_error`) after is not below the start's: the start is
   kept and the result says so.

The profile is written in the lens-profile format (:mod:`solidkit.camera.lens`) at the frame's
size, so ``solidkit capture unwarp --profile PROFILE.json`` uses it directly.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from solidkit.calibration.circles import Circle, find_image_circles
from solidkit.calibration.disparity import (
    MIN_MATCHES,
    SeamDisparity,
    SeamMatches,
    disparity_warning,
    match_disparity,
    seam_disparity,
    seam_matches,
    summarize,
)
from solidkit.calibration.fitcheck import SEAM_ERROR_WARN
from solidkit.calibration.overlap import refine_overlap
from solidkit.calibration.seam import WORK_RADIUS_PX, SeamImage, prepare_seam_image, seam_error
from solidkit.calibration.upright import UprightEstimate, estimate_upright
from solidkit.camera.dualfisheye import read_linear
from solidkit.camera.lens import (
    LensModel,
    LensProfile,
    fit_odd_poly,
    list_profiles,
    load_profile,
    project,
    rotation_to_ypr_deg,
)
from solidkit.document import make_provenance
from solidkit.envmap.coords import rotation_from_ypr, rotation_z
from solidkit.envmap.resample import sample_image
from solidkit.envmap.sun import luminance
from solidkit.errors import InputError

__all__ = [
    "FAMILIES",
    "MIN_HALF_FOV_DEG",
    "MAX_HALF_FOV_DEG",
    "MAX_CENTER_FRAC",
    "LensFit",
    "family_lens",
    "start_profile",
    "upright_of",
    "fit_dual_fisheye",
    "fit_file",
    "back_tilt_deg",
    "disparity_warnings",
    "shipped_profile_warning",
    "SHIPPED_BETTER_DEG",
    "MAX_BACK_TILT_DEG",
]

FAMILIES = ("equidistant", "equisolid", "theta")
MIN_HALF_FOV_DEG = 94.0
MAX_HALF_FOV_DEG = 115.0
MAX_CENTER_FRAC = 0.03
#: The back lens' axis is within this angle (degrees) of exactly opposite the front's: a rigid twin-lens body
#: (one Theta SC measured in Hugin: 1.2° yaw, 1.1° pitch off); ``--max-back-tilt-deg`` widens it.
MAX_BACK_TILT_DEG = 3.0


def _finite(v: dict) -> float:
    """A seam error for scans: inf when undefined or when the lenses overlap on less than 90 % of the ring
    (a candidate that looks good on a part of the ring only is a degenerate escape)."""
    e = v["seam_error"]
    return e if math.isfinite(e) and v["coverage"] >= 0.9 else math.inf


_EDGE_MARGIN = 0.01  # the usable field ends 1 % of the radius inside the fitted circle (soft edge)


@lru_cache(maxsize=1)
def _theta_table() -> tuple[np.ndarray, np.ndarray]:
    lens = load_profile("theta-v").lenses[0]
    assert lens.table is not None
    return np.radians(lens.table.theta_deg), np.asarray(lens.table.r_px, np.float64)


def _shape(family: str, theta: np.ndarray) -> np.ndarray:
    if family == "equidistant":
        return theta
    if family == "equisolid":
        return 2.0 * np.sin(theta / 2.0)
    if family == "theta":
        t, r = _theta_table()
        g = r / r[1] * t[1]  # ~theta near the axis
        end_slope = (g[-1] - g[-2]) / (t[-1] - t[-2])
        return np.where(theta <= t[-1], np.interp(theta, t, g), g[-1] + end_slope * (theta - t[-1]))
    raise InputError(f"unknown projection family {family!r}; known: {', '.join(FAMILIES)}")


def _max_half_fov(family: str) -> float:
    return math.degrees(_theta_table()[0][-1]) + 3.0 if family == "theta" else MAX_HALF_FOV_DEG


@lru_cache(maxsize=4096)
def _unit_poly(family: str, half_fov_deg: float) -> tuple[float, ...]:
    """Odd polynomial of ``g(theta)`` on [0, half_fov] (``k = 1``; scans reuse it for every circle)."""
    if family == "equidistant":
        return (1.0,)
    grid = np.linspace(0.0, math.radians(half_fov_deg), 200)
    return tuple(fit_odd_poly(grid, _shape(family, grid), 11))


@lru_cache(maxsize=8)
def _shape_inverse(family: str) -> tuple[np.ndarray, np.ndarray]:
    """``(theta, g(theta))`` on a dense grid to 125°: ``np.interp(g, table[1], table[0])`` inverts ``g``."""
    grid = np.linspace(0.0, math.radians(125.0), 8193)
    return grid, np.asarray(_shape(family, grid), np.float64)


def family_lens(name: str, family: str, circle: Circle, half_fov_deg: float, R: np.ndarray) -> LensModel:
    """A lens of ``family`` whose half field ``half_fov_deg`` falls on ``circle`` (rotation ``R`` lens -> camera)."""
    k = circle.r / float(_shape(family, np.array(math.radians(half_fov_deg))))
    poly = [k * c for c in _unit_poly(family, round(float(half_fov_deg), 6))]
    usable = circle.r * (1 - _EDGE_MARGIN)
    lens = LensModel(
        name=name, center=(circle.cx, circle.cy), poly=poly, max_angle_deg=half_fov_deg, ypr_deg=rotation_to_ypr_deg(R)
    )
    return lens.model_copy(update={"max_angle_deg": float(math.degrees(lens.angle(usable)))})


@lru_cache(maxsize=1024)
def _rotations(
    back_turn_deg: float, roll_deg: float, back_offset_deg: tuple[float, float] = (0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    Rr = np.asarray(rotation_z(math.radians(roll_deg)), np.float64)
    yaw, pitch = (math.radians(a) for a in back_offset_deg)
    back = np.asarray(rotation_from_ypr(math.pi + yaw, pitch, 0.0), np.float64) @ np.asarray(
        rotation_z(math.radians(back_turn_deg)), np.float64
    )
    return Rr, Rr @ back


def start_profile(
    circles: list[Circle],
    size: tuple[int, int],
    family: str,
    half_fov_deg: float | tuple[float, float],
    back_turn_deg: float = 0.0,
    roll_deg: float = 0.0,
    model: str = "dual-fisheye",
    back_offset_deg: tuple[float, float] = (0.0, 0.0),
) -> LensProfile:
    """Two-lens profile at ``size = (W, H)``: front on ``circles[0]``, back (yaw 180° + ``back_offset_deg[0]``,
    pitch ``back_offset_deg[1]``, its circle turned by ``back_turn_deg``) on ``circles[1]``, the
    camera rolled by ``roll_deg``."""
    fovs: tuple[Any, ...] = (half_fov_deg, half_fov_deg) if np.isscalar(half_fov_deg) else tuple(half_fov_deg)  # type: ignore[arg-type]  # np.isscalar does not narrow
    R0, R1 = _rotations(float(back_turn_deg), float(roll_deg), tuple(float(a) for a in back_offset_deg))
    lenses = [
        family_lens("front", family, circles[0], float(fovs[0]), R0),
        family_lens("back", family, circles[1], float(fovs[1]), R1),
    ]
    return LensProfile(model=model, source="solidkit calibrate fisheye", reference_size=tuple(size), lenses=lenses)


def upright_of(seam: SeamImage, profile: LensProfile) -> UprightEstimate:
    """:func:`~solidkit.calibration.upright.estimate_upright` of the panorama ``profile`` makes of the frame."""
    prof = profile.scaled(*seam.size)

    def sample(d: np.ndarray) -> np.ndarray:
        best = np.full(len(d), -np.inf)
        out = np.full(len(d), np.nan, np.float32)
        for lens in prof.lenses:
            x, y, th = project(lens, d)
            m = math.radians(lens.max_angle_deg) - th
            v = sample_image(seam.log_lum_all, x, y, border_value=np.nan)
            take = (m > best) & (m > 0)
            out = np.where(take, v, out)
            best = np.where(take, m, best)
        return out

    return estimate_upright(sample)


@dataclass
class LensFit:
    """What :func:`fit_dual_fisheye` found (module docstring); angles in degrees, pixels at the frame's size."""

    profile: LensProfile
    start: LensProfile
    circles: list[Circle]
    arrangement: str
    back_turn_deg: float
    family: str
    half_fov_deg: float
    upright: UprightEstimate
    seam_start: dict[str, float]
    seam_final: dict[str, float]
    refined: bool
    refusal: str | None
    disparity: SeamDisparity | None = None
    scans: dict[str, Any] = field(default_factory=dict)
    refinement: dict[str, Any] = field(default_factory=dict)

    @property
    def layout(self) -> str:
        turn = {0.0: "upright", 90.0: "rotated +90°", -90.0: "rotated -90°", 180.0: "upside down"}[
            self.upright.roll_deg
        ]
        return f"{self.arrangement.replace('_', ' ')}, {turn}"


def _scan_fov(
    seams: tuple[SeamImage, SeamImage], circles, size, family, back_turn, offset
) -> tuple[float, float, list]:
    """Coarse to fine: 0.25° steps on the frame reduced to ~128 px radius (a wider valley), then
    0.05° steps within ±0.4° at the working resolution (0.5° there moves the ring by ~1.5 px)."""

    def score(seam: SeamImage, hf: float) -> float:
        return _finite(
            seam_error(
                seam, start_profile(circles, size, family, hf, back_turn, back_offset_deg=offset), n=6000, edge_px=1.0
            )
        )

    hi = _max_half_fov(family)
    coarse = [(hf, score(seams[0], hf)) for hf in np.arange(MIN_HALF_FOV_DEG, hi + 1e-9, 0.25)]
    best = min(coarse, key=lambda t: t[1])[0]
    fine = [
        (hf, score(seams[1], hf))
        for hf in np.arange(max(MIN_HALF_FOV_DEG, best - 0.4), min(hi, best + 0.4) + 1e-9, 0.05)
    ]
    hf, val = min(fine, key=lambda t: t[1])
    return float(hf), float(val), [[round(a, 2), round(b, 5)] for a, b in coarse]


def _refine(
    images: list[np.ndarray],
    start: LensProfile,
    saturation: float | None,
    seam: SeamImage,
    log: Callable[[str], None],
    max_rotation_deg: float = MAX_BACK_TILT_DEG,
) -> tuple[LensProfile, dict]:
    """Bounded multi-start refinement (module docstring, step 5)."""
    r = float(np.mean([l.max_radius() for l in start.lenses]))
    levels = tuple(f for f in (8, 4, 2, 1) if r / f >= 48 and r / f <= 700) or (1,)
    bounds: dict[str, Any] = dict(
        max_center_px=MAX_CENTER_FRAC * r, max_log_scale=0.03, max_rotation_deg=max(max_rotation_deg, 0.1)
    )
    starts = [np.zeros(9)]
    for axis in (0, 1):
        for sgn in (-1, 1):
            p = np.zeros(9)
            p[6 + axis] = sgn * math.radians(1.0)
            starts.append(p)
    trials = []
    for i, p0 in enumerate(starts):
        res = refine_overlap(
            images, start, levels=levels[:1], saturation=saturation, start=p0, n_samples=4000, max_nfev=20, **bounds
        )
        e = seam_error(seam, res.profile)["seam_error"]
        trials.append((e, i, res))
        log(f"  start {i + 1}/{len(starts)}: seam error {e:.3f} after the coarse level (1/{levels[0]})")
    e, i, res = min(trials, key=lambda t: t[0] if math.isfinite(t[0]) else math.inf)
    if len(levels) > 1:
        res = refine_overlap(
            images,
            start,
            levels=levels[1:],
            saturation=saturation,
            start=res.params[:9],
            n_samples=8000,
            max_nfev=40,
            **bounds,
        )
    info = {
        "levels": list(levels),
        "starts": [[float(t[0]), int(t[1])] for t in trials],
        "chosen_start": int(i),
        "center_shift_px": res.center_shift_px,
        "scale": res.scale,
        "back_rotation_change_deg": res.rotation_change_deg,
        "bounds": bounds,
    }
    return res.profile, info


def back_tilt_deg(profile: LensProfile) -> float:
    """Angle (degrees) between the back lens' axis and the direction exactly opposite the front lens' axis."""
    a = profile.lenses[0].rotation[:, 2]
    b = profile.lenses[1].rotation[:, 2]
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(-a, b))), float(-a @ b)))


#: The match fit's noise model: a match's disparity (degrees) and an image circle's centre as the lens' optical
#: centre (a fraction of the radius: 0.6 px at 150 px, where rendered circles are found to 0.5 px; real rims are
#: less exact).
MATCH_SIGMA_DEG = 0.1
CENTRE_SIGMA_FRAC = 0.002


@dataclass
class _Geometry:
    """A profile's free geometry for the match fit: both half fields, the back lens' aim off opposite (yaw, pitch)
    and its extra turn about its axis (degrees)."""

    family: str
    half_fov_deg: tuple[float, float]
    offset_deg: tuple[float, float]
    turn_deg: float
    shift_px: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # the lens centres off the circles' (x, y)
    median_deg: float = math.nan
    matches: int = 0

    def profile(self, circles: list[Circle], size: tuple[int, int], back_turn: float, roll: float = 0.0):
        sx = self.shift_px
        moved = [Circle(c.cx + sx[2 * i], c.cy + sx[2 * i + 1], c.r, c.inliers) for i, c in enumerate(circles[:2])]
        return start_profile(
            moved,
            size,
            self.family,
            self.half_fov_deg,
            back_turn + self.turn_deg,
            roll,
            back_offset_deg=self.offset_deg,
        )


def _fit_matches(
    matches: SeamMatches,
    circles: list[Circle],
    size: tuple[int, int],
    start: _Geometry,
    back_turn: float,
    max_tilt_deg: float,
) -> _Geometry:
    """Half fields, back-lens aim and lens centres minimising the matches' disparity (robust: soft L1 at 0.5°, then
    the matches beyond 4x the median, at least 1°, left out and fitted again), the aim within ``max_tilt_deg`` of
    opposite, the centres within :data:`MAX_CENTER_FRAC` of the radius of the image circles' centres."""
    hi = _max_half_fov(start.family)
    b = max(max_tilt_deg, 1e-3)
    c = MAX_CENTER_FRAC * float(np.mean([ci.r for ci in circles[:2]]))
    centre_sigma = CENTRE_SIGMA_FRAC * float(np.mean([ci.r for ci in circles[:2]]))
    lower = [MIN_HALF_FOV_DEG, MIN_HALF_FOV_DEG, -b, -b, -b, -c, -c, -c, -c]
    upper = [hi, hi, b, b, b, c, c, c, c]
    x0 = np.clip([*start.half_fov_deg, *start.offset_deg, start.turn_deg, *start.shift_px], lower, upper)

    def geometry(x: np.ndarray) -> _Geometry:
        return _Geometry(
            start.family,
            (float(x[0]), float(x[1])),
            (float(x[2]), float(x[3])),
            float(x[4]),
            (float(x[5]), float(x[6]), float(x[7]), float(x[8])),
        )

    keep = np.ones(len(matches.p0), bool)
    W, H = matches.size
    sx, sy = size[0] / W, size[1] / H  # the matches' pixels -> the circles' (the frame's) pixels
    pts = [np.asarray(m, np.float64) * [sx, sy] for m in (matches.p0, matches.p1)]
    inv = _shape_inverse(start.family)

    def disparity(x: np.ndarray, sel: np.ndarray) -> np.ndarray:
        """:func:`match_disparity` of ``geometry(x)`` (what :func:`start_profile` builds, without building it)."""
        Rs = _rotations(float(back_turn + x[4]), 0.0, (float(x[2]), float(x[3])))
        dirs = []
        for i in range(2):
            c = circles[i]
            d = pts[i][sel] - [c.cx + x[5 + 2 * i], c.cy + x[6 + 2 * i]]
            r = np.hypot(d[:, 0], d[:, 1])
            g_edge = float(_shape(start.family, np.array(math.radians(x[i]))))
            th = np.interp(r * (g_edge / c.r), inv[1], inv[0])
            u = d / np.maximum(r, 1e-12)[:, None]
            st = np.sin(th)
            dirs.append(np.stack([st * u[:, 0], st * u[:, 1], np.cos(th)], axis=-1) @ Rs[i].T)
        e = dirs[0] - dirs[1]
        return np.degrees(2.0 * np.arcsin(np.minimum(0.5 * np.sqrt(np.einsum("ij,ij->i", e, e)), 1.0)))

    def resid(x: np.ndarray) -> np.ndarray:
        disp = disparity(x, keep)
        over = max(0.0, math.hypot(x[2], x[3]) - max_tilt_deg)  # the aim's bound is a cone, the box a square
        # the circles' centres are measured too: a shift by their uncertainty costs as much as one match 0.1° off
        return np.concatenate([disp, [100.0 * over], np.asarray(x[5:9]) * (MATCH_SIGMA_DEG / centre_sigma)])

    x = x0
    for _ in range(2):
        sol = least_squares(
            resid,
            x,
            bounds=(lower, upper),
            loss="soft_l1",
            f_scale=0.5,
            diff_step=1e-4,
            max_nfev=30,
            ftol=1e-5,
            xtol=1e-6,
        )
        x = sol.x
        disp = disparity(x, np.ones(len(keep), bool))
        new = disp <= max(1.0, 4.0 * float(np.median(disp)))
        if new.sum() < MIN_MATCHES or np.array_equal(new, keep):
            break
        keep = new
    g = geometry(x)
    disp = match_disparity(g.profile(circles, size, back_turn), matches)[0]
    g.median_deg, g.matches = float(np.median(disp)), len(disp)
    return g


def _with_edge(profile: LensProfile, circles: list[Circle]) -> LensProfile:
    """Usable field = where r(theta) reaches 1 % inside each fitted circle, after refinement scaled r."""
    lenses = []
    for lens, c in zip(profile.lenses, circles):
        reach = c.r * (1 - _EDGE_MARGIN) - math.hypot(lens.center[0] - c.cx, lens.center[1] - c.cy)
        lenses.append(lens.model_copy(update={"max_angle_deg": float(math.degrees(lens.angle(reach)))}))
    return profile.model_copy(update={"lenses": lenses})


def fit_dual_fisheye(
    image: np.ndarray,
    saturation: float | None = None,
    *,
    families: tuple[str, ...] = FAMILIES,
    refine: bool = True,
    max_back_tilt_deg: float = MAX_BACK_TILT_DEG,
    log: Callable[[str], None] = lambda s: None,
) -> LensFit:
    """A starting lens profile (and its refinement) from one linear dual-fisheye frame ``(H, W, 3)``.

    ``saturation``: linear clipping level of the frame (``None``: HDR); ``max_back_tilt_deg``: how far the
    back lens' axis may be from exactly opposite the front's (degrees). Steps: module docstring.
    Raises :class:`~solidkit.calibration.circles.CircleError` (an InputError) when the frame shows
    no two image circles.
    """
    img = np.asarray(image, np.float32)
    if img.ndim != 3 or img.shape[0] < 16 or img.shape[1] < 16:
        raise InputError(f"expected an (H, W, 3) image of at least 16x16 px, got shape {img.shape}")
    for f in families:
        _shape(f, np.array(1.0))  # unknown names fail before any work
    H, W = img.shape[:2]
    size = (W, H)
    lum = luminance(img[..., :3])
    circles, arrangement = find_image_circles(lum)
    log(
        f"image circles ({arrangement.replace('_', ' ')}): "
        + "; ".join(f"({c.cx:.1f}, {c.cy:.1f}) r {c.r:.1f} px" for c in circles)
    )
    radius = float(np.mean([c.r for c in circles]))
    seam = prepare_seam_image(img, radius, saturation)
    seam_coarse = prepare_seam_image(img, radius * WORK_RADIUS_PX / 128.0, saturation)

    seam_rough = prepare_seam_image(img, radius * WORK_RADIUS_PX / 64.0, saturation)
    turns, turn_hf = {}, {}
    for turn in (0.0, 90.0, 180.0, -90.0):  # every field of view in 1° steps at ~64 px radius (a wide valley)
        vals = {
            hf: _finite(
                seam_error(seam_rough, start_profile(circles, size, "equidistant", hf, turn), n=4000, edge_px=0.5)
            )
            for hf in np.arange(MIN_HALF_FOV_DEG, MAX_HALF_FOV_DEG + 1e-9, 1.0)
        }
        turn_hf[turn] = min(vals, key=vals.__getitem__)
        turns[turn] = vals[turn_hf[turn]]
    back_turn = min(turns, key=turns.__getitem__)
    log(
        f"back circle turned by {back_turn:+.0f}° relative to the front (seam {turns[back_turn]:.4f}; others "
        + ", ".join(f"{k:+.0f}°: {v:.4f}" for k, v in turns.items() if k != back_turn)
        + ")"
    )

    # the back lens' aim: yaw/pitch offsets from exactly opposite (real units and video layouts are off by
    # degrees); the aim and the field of view trade off, so they alternate (equidistant), twice
    if not (math.isfinite(max_back_tilt_deg) and 0.0 <= max_back_tilt_deg <= 30.0):
        raise InputError(f"--max-back-tilt-deg must be within 0..30 degrees, got {max_back_tilt_deg}")
    step = 1.0 if max_back_tilt_deg <= 5.0 else 2.0
    reach = math.floor(max_back_tilt_deg / step) * step
    grid = [(0.0, 0.0)] + [
        (float(y), float(p))
        for y in np.arange(-reach, reach + 1e-9, step)
        for p in np.arange(-reach, reach + 1e-9, step)
        if (y, p) != (0.0, 0.0) and math.hypot(y, p) <= max_back_tilt_deg + 1e-9
    ]
    offset, aims, scanned = (0.0, 0.0), {}, {}
    for _ in range(2):
        scanned[offset] = _scan_fov((seam_coarse, seam), circles, size, "equidistant", back_turn, offset)
        hf_eq = scanned[offset][0]
        aims = {
            off: _finite(
                seam_error(
                    seam_coarse,
                    start_profile(circles, size, "equidistant", hf_eq, back_turn, back_offset_deg=off),
                    n=6000,
                    edge_px=1.0,
                )
            )
            for off in grid
        }
        best = min(aims, key=aims.__getitem__)
        new = best if aims[best] <= 0.97 * aims[(0.0, 0.0)] else (0.0, 0.0)  # an off-axis aim must earn its place
        if new == offset:
            break
        offset = new
    log(
        f"back lens aim: yaw {180 + offset[0]:.0f}°, pitch {offset[1]:+.0f}° (seam {aims[offset]:.3f}; exactly "
        f"opposite: {aims[(0.0, 0.0)]:.3f})"
    )

    fam_scores: dict[str, dict[str, Any]] = {}
    for fam in families:
        hf, val, curve = (
            scanned[offset]
            if fam == "equidistant" and offset in scanned
            else _scan_fov((seam_coarse, seam), circles, size, fam, back_turn, offset)
        )
        fam_scores[fam] = {"half_fov_deg": hf, "seam_error": val, "scan": curve}
        log(f"family {fam}: best field of view {2 * hf:.1f}° (seam {val:.4f})")
    family = min(fam_scores, key=lambda f: fam_scores[f]["seam_error"])
    half_fov = fam_scores[family]["half_fov_deg"]
    if not math.isfinite(fam_scores[family]["seam_error"]):
        raise InputError(
            "the two image circles do not overlap in any field of view up to "
            f"{2 * MAX_HALF_FOV_DEG:.0f}°: not a dual-fisheye frame of one camera?"
        )

    # the geometry from scene points both lenses show (module docstring, step 3b): matched once under the best
    # start, every family's fields and back-lens aim fitted to them, the best family matched again and refitted
    geo = {fam: _Geometry(fam, (v["half_fov_deg"],) * 2, offset, 0.0) for fam, v in fam_scores.items()}
    matches = seam_matches(img, geo[family].profile(circles, size, back_turn), circles)
    by_matches = len(matches.p0) >= MIN_MATCHES
    if by_matches:
        for fam in families:
            geo[fam] = _fit_matches(matches, circles, size, geo[fam], back_turn, max_back_tilt_deg)
            fam_scores[fam]["disparity_median_deg"] = geo[fam].median_deg
            log(
                f"family {fam} fitted to {len(matches.p0)} matched scene points: field of view "
                f"{sum(geo[fam].half_fov_deg):.2f}°, back lens aim ({geo[fam].offset_deg[0]:+.2f}°, "
                f"{geo[fam].offset_deg[1]:+.2f}°), median disparity {geo[fam].median_deg:.3f}°"
            )
        family = min(families, key=lambda f: geo[f].median_deg)
        for _ in range(3):  # matched again under the better profile: more of the overlap's points match
            again = seam_matches(img, geo[family].profile(circles, size, back_turn), circles)
            if len(again.p0) < MIN_MATCHES:
                break
            refit = _fit_matches(again, circles, size, geo[family], back_turn, max_back_tilt_deg)
            done = refit.median_deg >= 0.95 * summarize(geo[family].profile(circles, size, back_turn), again).median_deg
            matches, geo[family] = again, refit
            fam_scores[family]["disparity_median_deg"] = refit.median_deg
            if done:
                break
        half_fov = float(np.mean(geo[family].half_fov_deg))
        log(f"kept {family} by the matches: median disparity {geo[family].median_deg:.3f}° over {len(matches.p0)}")
    else:
        log(f"only {len(matches.p0)} scene points matched across the overlap: the seam error decides alone")

    up = upright_of(seam, geo[family].profile(circles, size, back_turn))
    log(f"upright: roll {up.roll_deg:+.0f}° ({up.cue}{'' if up.confident else ', not confident'})")
    # without matches, refine every family whose start is within 15 % of the best: the overlap ring is narrow, so
    # the families' shapes differ little there and the refined seam decides
    best_start = fam_scores[family]["seam_error"]
    tried = [family] + [
        f
        for f in fam_scores
        if f != family and refine and not by_matches and fam_scores[f]["seam_error"] <= 1.15 * best_start
    ]
    outcomes = []
    for fam in tried:
        g = geo[fam]
        hf = float(np.mean(g.half_fov_deg))
        start = g.profile(circles, size, back_turn, up.roll_deg)
        e0 = seam_error(seam, start)
        d0 = summarize(start, matches).median_deg if by_matches else math.nan
        log(f"start profile: {fam}, field of view {2 * hf:.1f}°, seam error {e0['seam_error']:.3f}")
        info: dict[str, Any]
        final, refused, info, e1 = start, None, {}, e0
        if refine:
            log("refining on the overlap (bounded, 5 starts, coarse to fine)")
            refined, info = _refine(
                [img], start, saturation, seam, log, max(0.0, max_back_tilt_deg - back_tilt_deg(start))
            )
            refined = _with_edge(refined, circles)
            e1 = seam_error(seam, refined)
            d1 = summarize(refined, matches).median_deg if by_matches else math.nan
            why = []
            if not (math.isfinite(e1["seam_error"]) and e1["seam_error"] < e0["seam_error"]):
                why.append(f"seam error {e1['seam_error']:.3f} after vs {e0['seam_error']:.3f} at the start")
            if by_matches and not d1 <= d0 + 0.02:
                why.append(f"median disparity {d1:.3f}° after vs {d0:.3f}° at the start")
            if back_tilt_deg(refined) > max_back_tilt_deg + 1e-6:
                why.append(f"back lens {back_tilt_deg(refined):.2f}° off opposite > {max_back_tilt_deg:g}°")
            if why:
                refused = "refinement refused: " + "; ".join(why) + "; the start profile is kept"
                log(refused)
            else:
                final = refined
        kept = e1 if refused is None else e0
        outcomes.append((_finite({**kept, "coverage": 1.0}), fam, hf, start, e0, final, refused, info, e1))
    _, family, half_fov, start, e0, final, refused, info, e1 = min(outcomes, key=lambda o: o[0])
    if len(outcomes) > 1:
        log(f"kept {family}: seam error " + ", ".join(f"{o[1]} {o[0]:.3f}" for o in outcomes))
    disparity = seam_disparity(img, final, circles)  # matched afresh under the profile kept
    log(
        f"seam disparity: median {disparity.median_deg:.3f}°, p95 {disparity.p95_deg:.3f}°, "
        f"{100 * disparity.doubled_fraction:.0f} % of {disparity.matches} matches more than 1° apart"
    )
    return LensFit(
        profile=final,
        start=start,
        circles=circles,
        arrangement=arrangement,
        back_turn_deg=back_turn,
        family=family,
        half_fov_deg=half_fov,
        upright=up,
        seam_start=e0,
        seam_final=e1 if refused is None else e0,
        refined=refine and refused is None,
        refusal=refused,
        disparity=disparity,
        scans={
            "back_turn_seam_error": {str(k): v for k, v in turns.items()},
            "back_offset_deg": list(offset),
            "fitted_to_matches": by_matches,
            "matches": len(matches.p0),
            "families": fam_scores,
            "refined_seam": e1,
        },
        refinement={**info, "families_refined": {o[1]: o[0] for o in outcomes}},
    )


def disparity_warnings(disparity: SeamDisparity | None, seam_error_value: float) -> list[str]:
    """What ``calibrate fisheye`` says of a profile's fit, by the rule ``capture unwarp`` applies
    (:mod:`solidkit.calibration.fitcheck`): ``seam_disparity`` when the lenses put the same scene points more than
    :data:`~solidkit.calibration.disparity.DISPARITY_WARN_DEG` apart (median) or half the matches more than 1° apart
    (:func:`~solidkit.calibration.disparity.disparity_warning`), or when that cannot be measured; where it cannot,
    ``seam_mismatch`` above the seam error ``capture unwarp`` then warns at."""
    out = []
    if disparity is None or not disparity.measured:
        n = 0 if disparity is None else disparity.matches
        out.append(
            f"seam_disparity: unmeasured ({n} scene points matched across the overlap: too little texture there); "
            "check the panorama's seams by eye"
        )
        if math.isfinite(seam_error_value) and seam_error_value > SEAM_ERROR_WARN:
            out.append(
                f"seam_mismatch: seam error {seam_error_value:.2f} > {SEAM_ERROR_WARN}: 'capture unwarp' will warn "
                "(its photometric check where the disparity is unmeasured)"
            )
    else:
        doubled = disparity_warning(disparity)
        if doubled is not None:
            out.append(doubled)
    return out


#: A shipped profile is said to fit a frame better than the fit when its median seam disparity is lower by this much
#: (degrees; 1.5 px at 5376 px, below what a person sees) or by a fifth.
SHIPPED_BETTER_DEG = 0.1


def shipped_profile_warning(
    ours: SeamDisparity | None,
    our_seam_error: float,
    shipped_disparity: dict[str, SeamDisparity],
    shipped_seam_error: dict[str, float],
    shipped_back_tilt_deg: dict[str, float],
    max_back_tilt_deg: float,
) -> str | None:
    """``shipped_profile_fits_better`` when a shipped profile of the frame's layout fits it better than the fit: a
    median seam disparity lower by :data:`SHIPPED_BETTER_DEG` or by a fifth (by the seam error, 10 % lower, where the
    disparity is unmeasured). The best such profile is named, and so is its back lens' tilt where it exceeds the fit's
    bound: a shipped profile is used as it is (it was measured on a unit of that camera), while a fit of an unknown
    camera stays within ``max_back_tilt_deg`` (a rigid twin-lens body; a wider bound lets a single frame's parallax
    pull the back lens off, and fitted the real Theta S frame worse: 1.02° at 7.25°, against 0.79° within 3°)."""
    if ours is not None and ours.measured:
        d = ours.median_deg
        better = {
            k: v.median_deg
            for k, v in shipped_disparity.items()
            if v.measured and (v.median_deg < d - SHIPPED_BETTER_DEG or (d > 0.1 and v.median_deg < 0.8 * d))
        }
    else:
        better = {k: v for k, v in shipped_seam_error.items() if math.isfinite(v) and v < 0.9 * our_seam_error}
    if not better:
        return None
    best = min(better, key=lambda k: better[k])
    d = shipped_disparity[best].median_deg if best in shipped_disparity else math.nan
    text = (
        f"shipped_profile_fits_better: the shipped profile {best!r} fits this frame better (median seam disparity "
        f"{d:.2f}°, seam error {shipped_seam_error.get(best, math.nan):.3f}; this fit: "
        f"{ours.median_deg if ours is not None else math.nan:.2f}°, {our_seam_error:.3f}); "
        f"use --profile {best} or refine it with 'solidkit calibrate overlap --base {best}'"
    )
    tilt = shipped_back_tilt_deg.get(best, 0.0)
    if tilt > max_back_tilt_deg:
        text += (
            f"; its back lens is {tilt:.1f}° off opposite, beyond the {max_back_tilt_deg:g}° this fit may use "
            "(--max-back-tilt-deg): a shipped profile is used as it was measured, a fit of an unknown camera is held "
            "to the bound"
        )
    return text


def fit_file(
    path: str | Path,
    out: str | Path,
    *,
    families: tuple[str, ...] = FAMILIES,
    refine: bool = True,
    name: str | None = None,
    max_back_tilt_deg: float = MAX_BACK_TILT_DEG,
    log: Callable[[str], None] = lambda s: None,
) -> tuple[LensFit, dict]:
    """``solidkit calibrate fisheye``: fit a frame, write the lens profile to ``out``, return (fit, summary).

    The summary's ``seam_disparity`` (:func:`~solidkit.calibration.disparity.seam_disparity`, degrees) judges the
    profile: a median above :data:`~solidkit.calibration.disparity.DISPARITY_WARN_DEG` or more than half the matches
    over 1° apart is a ``seam_disparity`` warning (``ok`` false), as is an unmeasured one, and then a seam error above
    :data:`~solidkit.calibration.fitcheck.SEAM_ERROR_WARN` a ``seam_mismatch`` one (``capture unwarp``'s rule).
    """
    path, out = Path(path), Path(out)
    img, sat = read_linear(path)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    fit = fit_dual_fisheye(
        img[..., :3], sat, families=families, refine=refine, max_back_tilt_deg=max_back_tilt_deg, log=log
    )
    W, H = fit.profile.reference_size
    summary = {
        "output": str(out),
        "input": str(path),
        "size": [W, H],
        "layout": fit.layout,
        "arrangement": fit.arrangement,
        "roll_deg": fit.upright.roll_deg,
        "upright": fit.upright.to_json(),
        "back_turn_deg": fit.back_turn_deg,
        "family": fit.family,
        "fov_deg": round(2 * fit.half_fov_deg, 2),
        "families": {
            k: {"fov_deg": round(2 * v["half_fov_deg"], 2), "seam_error": v["seam_error"]}
            for k, v in fit.scans["families"].items()
        },
        "circles": [c.to_json() for c in fit.circles],
        "centers": [[round(l.center[0], 2), round(l.center[1], 2)] for l in fit.profile.lenses],
        "max_angle_deg": [round(l.max_angle_deg, 3) for l in fit.profile.lenses],
        "back_ypr_deg": [round(a, 3) for a in fit.profile.lenses[1].ypr_deg],
        "back_tilt_deg": round(back_tilt_deg(fit.profile), 3),
        "max_back_tilt_deg": max_back_tilt_deg,
        "seam_disparity": fit.disparity.to_json() if fit.disparity is not None else None,
        "seam_error_start": fit.seam_start["seam_error"],
        "seam_error_refined": fit.scans["refined_seam"]["seam_error"],
        "seam_error": fit.seam_final["seam_error"],
        "refined": fit.refined,
        "refusal": fit.refusal,
        "refinement": fit.refinement,
        "warnings": [],
    }
    # the shipped profiles of this frame's aspect, judged on the same frame: a user may hold a camera solidkit knows
    seam = prepare_seam_image(img[..., :3], float(np.mean([c.r for c in fit.circles])), sat)
    shipped, shipped_disp = {}, {}
    for pname in list_profiles():
        sp = load_profile(pname)
        if len(sp.lenses) == 2 and abs(sp.reference_size[0] / sp.reference_size[1] - W / H) < 0.01:
            shipped[pname] = seam_error(seam, sp.scaled(W, H))["seam_error"]
            shipped_disp[pname] = seam_disparity(img[..., :3], sp.scaled(W, H), fit.circles)
    summary["shipped_profiles_seam_error"] = shipped
    summary["shipped_profiles_disparity_deg"] = {k: v.to_json()["median_deg"] for k, v in shipped_disp.items()}
    ours = fit.disparity
    tilts = {k: back_tilt_deg(load_profile(k)) for k in shipped}
    summary["shipped_profiles_back_tilt_deg"] = {k: round(v, 2) for k, v in tilts.items()}
    note = shipped_profile_warning(ours, fit.seam_final["seam_error"], shipped_disp, shipped, tilts, max_back_tilt_deg)
    if note is not None:
        summary["warnings"].append(note)
    summary["warnings"] += disparity_warnings(ours, fit.seam_final["seam_error"])
    summary["ok"] = not any(w.startswith("seam_disparity") for w in summary["warnings"])
    if not fit.upright.confident:
        summary["warnings"].append(
            f"upright_uncertain: which way is up was decided by {fit.upright.cue} without a clear "
            "margin; check the panorama and fix the roll if it is sideways"
        )
    if fit.refusal:
        summary["warnings"].append(fit.refusal)
    prof = fit.profile.model_copy(
        update={
            "model": name or path.stem,
            "source": (
                f"solidkit calibrate fisheye on {path.name}: image circles fitted, {fit.family} projection with a "
                f"{2 * fit.half_fov_deg:.1f}° field from the circle radius and the overlap, layout {fit.layout}, "
                + ("refined on the overlap" if fit.refined else "not refined" + (" (refused)" if fit.refusal else ""))
            ),
            "residuals": {
                "seam_disparity": fit.disparity.to_json() if fit.disparity is not None else None,
                "back_tilt_deg": back_tilt_deg(fit.profile),
                "seam_error_start": fit.seam_start["seam_error"],
                "seam_error": fit.seam_final["seam_error"],
                "seam_error_refined": fit.scans["refined_seam"]["seam_error"],
                "refused": fit.refusal,
                "family": fit.family,
                "fov_deg": 2 * fit.half_fov_deg,
                "layout": fit.layout,
                "image_circles_px": [c.to_json() for c in fit.circles],
                "family_seam_error": {k: v["seam_error"] for k, v in fit.scans["families"].items()},
            },
            "provenance": make_provenance(
                [path],
                tool="solidkit calibrate fisheye",
                families=list(families),
                refine=refine,
                max_back_tilt_deg=max_back_tilt_deg,
            ),
            "notes": "A starting profile from one frame: check the panorama; refine further with 'solidkit calibrate "
            "overlap' on several outdoor frames of the same unit.",
        }
    )
    prof.save(out)
    summary["profile_key"] = prof.key()
    return fit, summary
