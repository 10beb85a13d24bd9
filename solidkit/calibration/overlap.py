"""Per-unit lens refinement from the overlap ring of dual-fisheye images.

Two fisheyes of ~200° see a ring of directions (about 80-100° from each lens axis) twice. A
correct profile maps each such direction to pixels that show the same scene point, so the
profile is refined by minimising the *photometric disagreement* of the lenses on that ring:

    r_k = log(g_n I_0(P_0(d_k)) + e) - log(I_1(P_1(d_k)) + e)

for ring directions ``d_k`` (a Fibonacci lattice in the camera frame) of every image ``n``,
where ``P_i`` is lens ``i``'s projection (:func:`solidkit.camera.lens.project`), ``I_i`` the
blurred luminance at the current pyramid level, ``g_n`` a per-image gain and ``e`` a small
floor. Parameters: each lens' centre offset ``(dx, dy)`` (px, full resolution) and log scale
of ``r(theta)``, and the back lens' 3-DoF rotation (a rotation vector ``w``, applied in the
camera frame: ``R_1' = Exp(w) R_1``). The front lens' rotation is held fixed: it defines the
camera frame (a common rotation of both lenses leaves the overlap unchanged).

Robustness: the parameters can be bounded (a wrong start cannot run across the frame) and
:func:`refine_files` refuses a result whose seam error (:mod:`solidkit.calibration.seam`) is not
below the start's. ``scipy.optimize.least_squares`` with the Cauchy loss, its scale set from the
residuals' MAD at each level, so moving people (different content in the two views) and
clipped or textureless sky (masked when saturated; zero gradient when flat) do not pull the
solution; several images of different scenes can be stacked. Coarse to fine: images downsampled
by 8, 4, 2, 1 (area) and blurred, parameters carried over. A weak prior (``scale_sigma``) keeps
the two scales from trading off along the ring's near-degenerate radial direction (it acts on
their difference only; their common scale is determined by the data).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from solidkit.calibration.circles import fit_image_circle
from solidkit.calibration.seam import prepare_seam_image, ring_directions, seam_error
from solidkit.camera.dualfisheye import get_maps, match_gains, read_linear, seam_disagreement, warp_lens
from solidkit.camera.lens import LensProfile, load_profile, project, rotation_to_ypr_deg
from solidkit.document import make_provenance
from solidkit.envmap.coords import rotation_from_rotvec
from solidkit.envmap.resample import sample_image
from solidkit.envmap.sun import luminance
from solidkit.errors import InputError

__all__ = ["RefineResult", "ring_directions", "apply_params", "refine_overlap", "fit_image_circle", "refine_files"]


def apply_params(base: LensProfile, p: np.ndarray) -> LensProfile:
    """Profile with the parameter vector applied (layout: module docstring; px at base size)."""
    lenses = []
    L = len(base.lenses)
    for i, lens in enumerate(base.lenses):
        dx, dy, ls = p[3 * i : 3 * i + 3]
        upd: dict[str, Any] = {
            "center": (lens.center[0] + dx, lens.center[1] + dy),
            "poly": [k * math.exp(ls) for k in lens.poly],
        }
        if i > 0:
            w = p[3 * L + 3 * (i - 1) : 3 * L + 3 * i]
            upd["ypr_deg"] = rotation_to_ypr_deg(np.asarray(rotation_from_rotvec(w)) @ lens.rotation)
        lenses.append(lens.model_copy(update=upd))
    return base.model_copy(update={"lenses": lenses})


@dataclass
class RefineResult:
    """Refined profile, parameter changes and fit quality."""

    profile: LensProfile
    params: np.ndarray
    center_shift_px: list[list[float]]
    scale: list[float]
    rotation_change_deg: float
    levels: list[dict] = field(default_factory=list)
    circles: list = field(default_factory=list)


def _luminance(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lum = luminance(img)
    return lum, np.zeros(lum.shape, bool)


def refine_overlap(
    images: list[np.ndarray],
    base: LensProfile,
    *,
    levels: tuple[int, ...] = (8, 4, 2, 1),
    ring_deg: tuple[float, float] | None = None,
    n_samples: int = 12000,
    saturation: float | None = 0.98,
    scale_sigma: float = 0.005,
    fix_scale: bool = False,
    max_nfev: int = 60,
    edge_px: float = 4.0,
    min_radius_px: float = 48.0,
    circle_sigma_px: float | None = 1.0,
    start: np.ndarray | None = None,
    max_center_px: float | None = None,
    max_log_scale: float | None = None,
    max_rotation_deg: float | None = None,
) -> RefineResult:
    """Refine ``base`` (a two-lens profile) on linear dual-fisheye ``images`` (all the same size).

    Parameters
    ----------
    images : list of (H, W[, C]) float arrays, linear.
    base : the model profile to start from (scaled to the images' size internally).
    levels : pyramid downsampling factors, coarse to fine.
    ring_deg : incidence-angle range on the front lens sampled on the ring; default
        ``[180 - m1, m0]`` from the lenses' max angles (80-100° for 100° lenses), less the
        directions within ``edge_px`` (pixels of each pyramid level) of an image circle's edge.
    min_radius_px : pyramid levels where an image circle is smaller than this are skipped.
    circle_sigma_px : start each lens' centre at its fitted image circle (:func:`fit_image_circle`)
        and keep a prior of this std (px, full resolution) toward it; ``None``/0: photometric only.
        The overlap alone hardly separates a common shift of both centres from a tilt of the back
        lens (on the ring both move content the same way), so some centre information is needed.
    saturation : pixels at/above this value (any channel) are ignored (``None`` for HDR).
    scale_sigma : prior std of the *difference* of the lenses' log scales (a front-up/back-down scale
        change moves the seam along the ring's near-degenerate radial direction).
    fix_scale : hold the scales at 1 (refine centres and rotation only).
    start : parameters to start from (layout: module docstring; centres in px of the images'
        size), e.g. a coarse result or one of several starts; default: zero, centres at the fitted circles.
    max_center_px, max_log_scale, max_rotation_deg : bounds of the parameters about ``base``
        (centre offsets per axis in px of the images' size, |log scale|, back-lens rotation per
        rotation-vector component in degrees); ``None``: unbounded. A wrong start (another camera's
        profile) then cannot drag the lenses across the frame chasing a spurious photometric minimum.

    Returns
    -------
    RefineResult with the refined profile at the base profile's reference size.
    """
    if len(base.lenses) != 2:
        raise InputError("overlap refinement needs a two-lens profile")
    if not images:
        raise InputError("no images to refine on")
    h, w = images[0].shape[:2]
    if any(im.shape[:2] != (h, w) for im in images):
        raise InputError("all images for one refinement must have the same size")
    prof = base.scaled(w, h)
    to_base = base.reference_size[0] / w
    m0, m1 = (lens.max_angle_deg for lens in prof.lenses)
    lo, hi = ring_deg if ring_deg is not None else (180.0 - m1, m0)
    if hi <= lo:
        raise InputError(f"the lenses do not overlap (ring {lo:.1f}-{hi:.1f} deg)")
    dirs = ring_directions(n_samples, lo, hi)
    lum_full = []
    for im in images:
        lum, _ = _luminance(np.asarray(im, np.float32))
        if saturation is not None:
            sat = (
                np.any(np.asarray(im)[..., :3] >= saturation, axis=-1)
                if np.asarray(im).ndim == 3
                else np.asarray(im) >= saturation
            )
            lum = np.where(sat, np.nan, lum).astype(np.float32)
        lum_full.append(lum)
    eps = 0.01 * float(np.nanmedian(np.concatenate([x[np.isfinite(x)].ravel()[::97] for x in lum_full])) + 1e-6)
    n_img = len(images)
    L = 2
    p = np.zeros(3 * L + 3 + n_img)
    # image-circle centres: start there and keep a weak prior (pins the ring's degenerate mode)
    circles: list[list[float] | None] = [None, None]
    if start is not None:
        p[: min(len(start), 3 * L + 3)] = np.asarray(start, np.float64)[: 3 * L + 3]
    if circle_sigma_px:
        lum_mean = np.nanmean(np.stack([np.nan_to_num(x) for x in lum_full]), axis=0)
        for i, lens in enumerate(prof.lenses):
            cx, cy, rad, inl = fit_image_circle(lum_mean, lens.center, lens.max_radius())
            if (
                math.isfinite(cx)
                and inl > 0.3
                and math.hypot(cx - lens.center[0], cy - lens.center[1]) < 0.1 * lens.max_radius()
            ):
                circles[i] = [cx, cy, rad, inl]
                if start is None:
                    p[3 * i], p[3 * i + 1] = cx - lens.center[0], cy - lens.center[1]
    circle_target = np.array(
        [
            (c[0] - lens.center[0], c[1] - lens.center[1]) if c is not None else (p[3 * i], p[3 * i + 1])
            for i, (c, lens) in enumerate(zip(circles, prof.lenses))
        ]
    ).ravel()
    lower = np.full_like(p, -np.inf)
    if max_center_px is not None:
        lower[[0, 1, 3, 4]] = -max_center_px
    if max_log_scale is not None:
        lower[[2, 5]] = -max_log_scale
    if max_rotation_deg is not None:
        lower[3 * L : 3 * L + 3] = -math.radians(max_rotation_deg)
    upper = -lower
    p = np.clip(p, lower, upper)
    has_circle = np.array([circles[0] is not None] * 2 + [circles[1] is not None] * 2)
    if fix_scale:
        free = np.array([True, True, False, True, True, False] + [True] * (3 + n_img))
    else:
        free = np.ones_like(p, bool)
    report = []

    for f in levels:
        f = max(1, int(f))
        pyr = []
        for lum in lum_full:
            x = np.nan_to_num(lum, nan=0.0)
            valid = np.isfinite(lum).astype(np.float32)
            if f > 1:
                x = cv2.resize(x, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
                valid = cv2.resize(valid, (x.shape[1], x.shape[0]), interpolation=cv2.INTER_AREA)
            x = cv2.GaussianBlur(x, (0, 0), 1.0)
            valid = cv2.GaussianBlur(valid, (0, 0), 1.0)
            pyr.append(np.where(valid > 0.999, np.log(np.maximum(x, 0) + eps), np.nan).astype(np.float32))
        lw, lh = pyr[0].shape[1], pyr[0].shape[0]
        sx = lw / w
        # keep only ring directions at least `edge_px` (this level's pixels) inside both image
        # circles: the blur mixes the dark outside of a circle into its last pixels
        start = p.copy()
        cur0 = apply_params(prof, start).scaled(lw, lh)
        keep = np.ones(len(dirs), bool)
        for lens in cur0.lenses:
            safe = lens.angle(lens.max_radius() - edge_px)
            keep &= project(lens, dirs)[2] <= safe
        if keep.sum() < 200 or cur0.lenses[0].max_radius() < min_radius_px:
            report.append({"downsample": f, "skipped": "image circles too small at this level"})
            continue
        dk = dirs[keep]

        # normalised parameters: 1 unit = 1 px of this level (centres), 1e-3 (log scale),
        # 1 px of rotation at the ring (rotation), 0.01 (log gain)
        r_ring = float(cur0.lenses[0].radius(math.pi / 2))
        unit = np.concatenate([[1.0 / sx, 1.0 / sx, 1e-3] * L, [1.0 / r_ring] * 3, [0.01] * n_img])[free]

        def residuals(q: np.ndarray, robust_only: bool = False) -> np.ndarray:
            full = p.copy()
            full[free] = q * unit
            cur = apply_params(prof, full).scaled(lw, lh) if (lw, lh) != (w, h) else apply_params(prof, full)
            out = []
            xy = [project(lens, dk) for lens in cur.lenses]
            for n in range(n_img):
                a = sample_image(pyr[n], xy[0][0], xy[0][1], border_value=np.nan)
                b = sample_image(pyr[n], xy[1][0], xy[1][1], border_value=np.nan)
                r = a + full[3 * L + 3 + n] - b
                out.append(np.where(np.isfinite(r), r, 0.0))
            res = np.concatenate(out)
            if robust_only:
                return res
            # priors as many small entries, so that they stay in the Cauchy loss' quadratic zone:
            # the differential scale and the centres' distance to the image circles
            m = max(1, len(res) // 20)
            extra = [res]
            if not fix_scale:
                extra.append(np.full(m, 0.5 * f_scale * (full[2] - full[5]) / scale_sigma))
            if circle_sigma_px and has_circle.any():
                dc = (np.array([full[0], full[1], full[3], full[4]]) - circle_target)[has_circle] / circle_sigma_px
                extra.append(np.repeat(0.5 * f_scale * dc, m))
            return np.concatenate(extra)

        def jacobian(q: np.ndarray) -> np.ndarray:
            """Central differences with a fixed step of 0.25 units (a quarter pixel)."""
            cols = []
            for j in range(q.size):
                e = np.zeros_like(q)
                e[j] = 0.25
                cols.append((residuals(q + e) - residuals(q - e)) / 0.5)
            return np.stack(cols, axis=1)

        q0 = p[free] / unit
        lb, ub = lower[free] / unit, upper[free] / unit
        span = np.where(np.isfinite(ub - lb), ub - lb, 0.0)
        q0 = np.clip(q0, lb + 1e-6 * span, ub - 1e-6 * span)
        r0 = residuals(q0, robust_only=True)
        nz = r0[r0 != 0]
        f_scale = max(1.4826 * float(np.median(np.abs(nz - np.median(nz)))) if nz.size else 0.05, 1e-3)
        sol = least_squares(
            residuals,
            q0,
            jac=jacobian,
            loss="cauchy",
            f_scale=f_scale,
            max_nfev=max_nfev,
            method="trf",
            bounds=(lb, ub),
        )
        r1 = residuals(sol.x, robust_only=True)
        p[free] = sol.x * unit
        report.append(
            {
                "downsample": f,
                "f_scale": f_scale,
                "nfev": int(sol.nfev),
                "samples": int(keep.sum()),
                "params": p.tolist(),
                "status": sol.message,
                "median_abs_residual_before": float(np.median(np.abs(r0[r0 != 0]))) if np.any(r0 != 0) else math.nan,
                "median_abs_residual_after": float(np.median(np.abs(r1[r1 != 0]))) if np.any(r1 != 0) else math.nan,
            }
        )
    # parameters are in pixels of the working size: convert centres to the base reference size
    p_base = p.copy()
    for i in range(L):
        p_base[3 * i : 3 * i + 2] *= to_base
    refined = apply_params(base, p_base)
    w_rot = p[3 * L : 3 * L + 3]
    return RefineResult(
        profile=refined,
        params=p_base,
        center_shift_px=[[float(p_base[3 * i]), float(p_base[3 * i + 1])] for i in range(L)],
        scale=[math.exp(p[3 * i + 2]) for i in range(L)],
        rotation_change_deg=math.degrees(float(np.linalg.norm(w_rot))),
        levels=report,
        circles=[None if c is None else [c[0] * to_base, c[1] * to_base, c[2] * to_base, c[3]] for c in circles],
    )


#: Bounds of ``solidkit calibrate overlap`` about the base profile: centre offsets (fraction of the
#: image-circle radius, per axis), |log scale|, back-lens rotation (degrees per rotation-vector axis).
#: Real units stay well inside (a Theta SC measured in Hugin: back lens 1.2° off; centres a few px).
BOUNDS = {"center_frac": 0.03, "log_scale": 0.03, "rotation_deg": 3.0}


def refine_files(
    paths: list,
    base: str,
    out: Any,
    *,
    circle_sigma_px: float | None = 1.0,
    scale_sigma: float = 0.005,
    fix_scale: bool = False,
) -> dict:
    """``solidkit calibrate overlap``: refine a model profile on capture files, write ``out`` (JSON).

    The refinement is bounded (:data:`BOUNDS`) and judged by the seam error
    (:func:`solidkit.calibration.seam.seam_error`, mean over the images): when it is not lower
    after than before, the result is **refused** and ``out`` gets the base profile's geometry with
    ``residuals.refused`` saying why. Frames whose image circles sit elsewhere than the base
    profile's (another camera or layout) get a ``profile_mismatch`` warning pointing to
    ``solidkit calibrate fisheye``.

    Returns a summary: parameter changes, per-level residuals, the seam error and the seam
    disagreement (median |difference| of the two lenses on the feather band, linear) before and
    after, averaged over the images, ``refused`` (None or the reason) and ``warnings``.
    """
    if not paths:
        raise InputError("no images given")
    prof = load_profile(base)
    images, sat = [], None
    for p in paths:
        img, s = read_linear(Path(p))
        images.append(img)
        sat = s if sat is None else sat
    h, w = images[0].shape[:2]
    if any(im.shape[:2] != (h, w) for im in images):
        raise InputError("all images for one refinement must have the same size")
    scaled = prof.scaled(w, h)
    radius = float(np.mean([lens.max_radius() for lens in scaled.lenses]))
    warnings = []
    lum0 = luminance(images[0])
    for k, lens in enumerate(scaled.lenses[:2]):
        cx, cy, r, inl = fit_image_circle(lum0, lens.center, lens.max_radius(), search=0.12, rel_threshold=0.25)
        off = math.hypot(cx - lens.center[0], cy - lens.center[1]) if math.isfinite(cx) else math.inf
        if not (inl >= 0.4 and off <= max(4.0, 0.05 * lens.max_radius())):
            warnings.append(
                f"profile_mismatch: lens {k}: the frame's image circle is not where {prof.model!r} puts it "
                f"({'none found' if not math.isfinite(off) else f'{off:.0f} px away'}): another camera or "
                "layout? 'solidkit calibrate fisheye FRAME' makes a starting profile from the frame itself"
            )
    res = refine_overlap(
        images,
        prof,
        saturation=sat,
        circle_sigma_px=circle_sigma_px,
        scale_sigma=scale_sigma,
        fix_scale=fix_scale,
        max_center_px=BOUNDS["center_frac"] * radius,
        max_log_scale=BOUNDS["log_scale"],
        max_rotation_deg=BOUNDS["rotation_deg"],
    )
    out_h = max(64, min(512, w // 4))
    seams = [prepare_seam_image(img, radius, sat) for img in images]

    def seam(profile: LensProfile) -> tuple[float, float]:  # (seam error, what `capture unwarp` reports as seam_mad)
        vals, errs = [], []
        for img, sm in zip(images, seams):
            maps, _ = get_maps(profile, (w, h), out_h)
            warped = [warp_lens(img.astype(np.float32, copy=False), maps, i) for i in range(len(profile.lenses))]
            vals.append(seam_disagreement(warped, maps, match_gains(warped, maps, sat))["seam_mad"])
            errs.append(seam_error(sm, profile)["seam_error"])
        return float(np.mean(errs)), float(np.mean(vals))

    (err_before, before), (err_after, after) = seam(prof), seam(res.profile)
    refused = None
    if not (math.isfinite(err_after) and math.isfinite(err_before)):
        refused = (
            f"refinement refused: the seam error cannot be measured with {prof.model!r} or the result (the overlap "
            "ring falls on black or clipped pixels); the base profile's geometry is kept"
        )
    elif not err_after < err_before:
        refused = (
            f"refinement refused: seam error {err_after:.3f} after vs {err_before:.3f} with {prof.model!r}; "
            "the base profile's geometry is kept"
        )
        warnings.append(refused)
    kept = prof if refused else res.profile
    refined = kept.model_copy(
        update={
            "model": f"{prof.model}-unit",
            "parent": prof.model,
            "source": f"refined by solidkit calibrate overlap on {len(paths)} image(s) from the {prof.model!r} profile "
            f"(whose source: {prof.source})" + (" -- REFUSED, base geometry kept" if refused else ""),
            "residuals": {
                "seam_error_before": err_before,
                "seam_error_after": err_after,
                "refused": refused,
                "seam_mad_linear_before": before,
                "seam_mad_linear_after": after,
                "center_shift_px": res.center_shift_px,
                "scale": res.scale,
                "back_rotation_change_deg": res.rotation_change_deg,
                "image_circles_px": res.circles,
                "levels": [{k: v for k, v in lv.items() if k != "params"} for lv in res.levels],
            },
            "provenance": make_provenance(
                paths,
                tool="solidkit calibrate overlap",
                circle_sigma_px=circle_sigma_px,
                scale_sigma=scale_sigma,
                fix_scale=fix_scale,
                bounds=BOUNDS,
            ),
        }
    )
    refined.save(out)
    return {
        "output": str(out),
        "base": prof.model,
        "images": len(paths),
        "seam_error_before": err_before,
        "seam_error_after": err_after,
        "refused": refused,
        "warnings": warnings,
        "seam_mad_before": before,
        "seam_mad_after": after,
        "center_shift_px": res.center_shift_px,
        "scale": res.scale,
        "back_rotation_change_deg": res.rotation_change_deg,
        "back_ypr_deg": list(refined.lenses[1].ypr_deg),
        "levels": refined.residuals["levels"],
    }
