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

from solidkit.calibration.circles import Circle, find_image_circles
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
]

FAMILIES = ("equidistant", "equisolid", "theta")
MIN_HALF_FOV_DEG = 94.0
MAX_HALF_FOV_DEG = 115.0
MAX_CENTER_FRAC = 0.03
MAX_BACK_OFFSET_DEG = 10.0


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
    images: list[np.ndarray], start: LensProfile, saturation: float | None, seam: SeamImage, log: Callable[[str], None]
) -> tuple[LensProfile, dict]:
    """Bounded multi-start refinement (module docstring, step 5)."""
    r = float(np.mean([l.max_radius() for l in start.lenses]))
    levels = tuple(f for f in (8, 4, 2, 1) if r / f >= 48 and r / f <= 700) or (1,)
    bounds: dict[str, Any] = dict(
        max_center_px=MAX_CENTER_FRAC * r, max_log_scale=0.03, max_rotation_deg=MAX_BACK_OFFSET_DEG
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
    log: Callable[[str], None] = lambda s: None,
) -> LensFit:
    """A starting lens profile (and its refinement) from one linear dual-fisheye frame ``(H, W, 3)``.

    ``saturation``: linear clipping level of the frame (``None``: HDR). Steps: module docstring.
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
    grid = [(0.0, 0.0)] + [
        (float(y), float(p))
        for y in np.arange(-MAX_BACK_OFFSET_DEG, MAX_BACK_OFFSET_DEG + 1e-9, 2.0)
        for p in np.arange(-MAX_BACK_OFFSET_DEG, MAX_BACK_OFFSET_DEG + 1e-9, 2.0)
        if (y, p) != (0.0, 0.0)
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

    up = upright_of(seam, start_profile(circles, size, family, half_fov, back_turn, back_offset_deg=offset))
    log(f"upright: roll {up.roll_deg:+.0f}° ({up.cue}{'' if up.confident else ', not confident'})")
    # refine every family whose start is within 15 % of the best: the overlap ring is narrow, so the
    # families' shapes differ little there and the refined seam decides
    best_start = fam_scores[family]["seam_error"]
    tried = [family] + [
        f for f in fam_scores if f != family and refine and fam_scores[f]["seam_error"] <= 1.15 * best_start
    ]
    outcomes = []
    for fam in tried:
        hf = fam_scores[fam]["half_fov_deg"]
        start = start_profile(circles, size, fam, hf, back_turn, up.roll_deg, back_offset_deg=offset)
        e0 = seam_error(seam, start)
        log(f"start profile: {fam}, field of view {2 * hf:.1f}°, seam error {e0['seam_error']:.3f}")
        info: dict[str, Any]
        final, refused, info, e1 = start, None, {}, e0
        if refine:
            log("refining on the overlap (bounded, 5 starts, coarse to fine)")
            refined, info = _refine([img], start, saturation, seam, log)
            refined = _with_edge(refined, circles)
            e1 = seam_error(seam, refined)
            if math.isfinite(e1["seam_error"]) and e1["seam_error"] < e0["seam_error"]:
                final = refined
            else:
                refused = (
                    f"refinement refused: seam error {e1['seam_error']:.3f} after vs {e0['seam_error']:.3f} at "
                    "the start; the start profile is kept"
                )
                log(refused)
        kept = e1 if refused is None else e0
        outcomes.append((_finite({**kept, "coverage": 1.0}), fam, hf, start, e0, final, refused, info, e1))
    _, family, half_fov, start, e0, final, refused, info, e1 = min(outcomes, key=lambda o: o[0])
    if len(outcomes) > 1:
        log(f"kept {family}: seam error " + ", ".join(f"{o[1]} {o[0]:.3f}" for o in outcomes))
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
        scans={
            "back_turn_seam_error": {str(k): v for k, v in turns.items()},
            "back_offset_deg": list(offset),
            "families": fam_scores,
            "refined_seam": e1,
        },
        refinement={**info, "families_refined": {o[1]: o[0] for o in outcomes}},
    )


def fit_file(
    path: str | Path,
    out: str | Path,
    *,
    families: tuple[str, ...] = FAMILIES,
    refine: bool = True,
    name: str | None = None,
    log: Callable[[str], None] = lambda s: None,
) -> tuple[LensFit, dict]:
    """``solidkit calibrate fisheye``: fit a frame, write the lens profile to ``out``, return (fit, summary)."""
    path, out = Path(path), Path(out)
    img, sat = read_linear(path)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    fit = fit_dual_fisheye(img[..., :3], sat, families=families, refine=refine, log=log)
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
    shipped = {}
    for pname in list_profiles():
        sp = load_profile(pname)
        if len(sp.lenses) == 2 and abs(sp.reference_size[0] / sp.reference_size[1] - W / H) < 0.01:
            shipped[pname] = seam_error(seam, sp.scaled(W, H))["seam_error"]
    summary["shipped_profiles_seam_error"] = shipped
    better = {k: v for k, v in shipped.items() if math.isfinite(v) and v < 0.9 * fit.seam_final["seam_error"]}
    if better:
        best = min(better, key=better.__getitem__)
        summary["warnings"].append(
            f"shipped_profile_fits_better: the shipped profile {best!r} has a seam error of "
            f"{better[best]:.3f} on this frame (this fit: {fit.seam_final['seam_error']:.3f}); "
            f"use --profile {best} or refine it with 'solidkit calibrate overlap --base {best}'"
        )
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
                [path], tool="solidkit calibrate fisheye", families=list(families), refine=refine
            ),
            "notes": "A starting profile from one frame: check the panorama; refine further with 'solidkit calibrate "
            "overlap' on several outdoor frames of the same unit.",
        }
    )
    prof.save(out)
    summary["profile_key"] = prof.key()
    return fit, summary
