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

Robustness: ``scipy.optimize.least_squares`` with the Cauchy loss, its scale set from the
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

from solidkit.camera.dualfisheye import get_maps, match_gains, read_linear, seam_disagreement, warp_lens
from solidkit.camera.lens import LensProfile, load_profile, project, rotation_to_ypr_deg
from solidkit.document import make_provenance
from solidkit.envmap.coords import rotation_from_rotvec
from solidkit.envmap.resample import sample_image
from solidkit.envmap.sun import luminance
from solidkit.errors import InputError

__all__ = ["RefineResult", "ring_directions", "apply_params", "refine_overlap", "fit_image_circle", "refine_files"]


def ring_directions(n: int, lo_deg: float, hi_deg: float) -> np.ndarray:
    """``(m, 3)`` quasi-uniform directions (Fibonacci lattice) whose angle to +z is in [lo, hi] degrees."""
    lo, hi = math.cos(math.radians(hi_deg)), math.cos(math.radians(lo_deg))
    i = np.arange(n) + 0.5
    z = lo + (hi - lo) * i / n
    phi = i * math.pi * (3 - math.sqrt(5))
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


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


def fit_image_circle(
    lum: np.ndarray, center: tuple[float, float], radius: float, *, n_rays: int = 720, search: float = 0.12,
    rel_threshold: float = 0.1,
) -> tuple[float, float, float, float]:
    """Centre and radius of a fisheye's image circle (the edge between image and the dark outside).

    Along ``n_rays`` rays from ``center``, the outermost radius within ``radius (1 ± search)``
    where the luminance exceeds ``rel_threshold`` times the ray's median just inside is an edge
    point; a circle is fitted to the edge points by linear least squares (Kasa), trimming points
    beyond 3 MADs (rays where dark content reaches the edge, the frame border, lens glints) for
    10 rounds. Returns ``(cx, cy, r, inlier_fraction)``; NaNs when fewer than 20 rays found an edge.
    """
    h, w = lum.shape[:2]
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    rs = np.arange(radius * (1 - search), radius * (1 + search), 0.25)
    X = center[0] + np.cos(ang)[:, None] * rs
    Y = center[1] + np.sin(ang)[:, None] * rs
    prof = sample_image(np.nan_to_num(lum.astype(np.float32)), X.ravel(), Y.ravel(), border_value=np.nan).reshape(X.shape)
    inner = np.nanmedian(prof[:, : max(2, len(rs) // 6)], axis=1)
    pts = []
    for i in range(n_rays):
        row = prof[i]
        above = np.nonzero(np.isfinite(row) & (row > rel_threshold * inner[i]))[0]
        if inner[i] <= 0 or not above.size or above[-1] >= len(rs) - 1:
            continue
        j = above[-1]  # sub-pixel: linear crossing between j and j + 1
        t = rel_threshold * inner[i]
        frac = (row[j] - t) / max(row[j] - row[j + 1], 1e-12) if np.isfinite(row[j + 1]) else 0.0
        x, y = X[i, j] + frac * (X[i, j + 1] - X[i, j]), Y[i, j] + frac * (Y[i, j + 1] - Y[i, j])
        if 1 <= x <= w - 2 and 1 <= y <= h - 2:
            pts.append((x, y))
    if len(pts) < 20:
        return math.nan, math.nan, math.nan, 0.0
    c = np.asarray(pts)
    keep = np.ones(len(c), bool)
    for _ in range(10):
        A = np.column_stack([2 * c[keep, 0], 2 * c[keep, 1], np.ones(keep.sum())])
        sol = np.linalg.lstsq(A, (c[keep] ** 2).sum(1), rcond=None)[0]
        r = math.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 0.0))
        res = np.hypot(c[:, 0] - sol[0], c[:, 1] - sol[1]) - r
        mad = float(np.median(np.abs(res[keep]))) if keep.any() else 0.0
        new = np.abs(res) <= max(0.5, 3 * 1.4826 * mad)
        if new.sum() < 20 or np.array_equal(new, keep):
            break
        keep = new
    return float(sol[0]), float(sol[1]), r, float(keep.mean() * len(c) / n_rays)


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
            sat = np.any(np.asarray(im)[..., :3] >= saturation, axis=-1) if np.asarray(im).ndim == 3 else np.asarray(im) >= saturation
            lum = np.where(sat, np.nan, lum).astype(np.float32)
        lum_full.append(lum)
    eps = 0.01 * float(np.nanmedian(np.concatenate([x[np.isfinite(x)].ravel()[::97] for x in lum_full])) + 1e-6)
    n_img = len(images)
    L = 2
    p = np.zeros(3 * L + 3 + n_img)
    # image-circle centres: start there and keep a weak prior (pins the ring's degenerate mode)
    circles: list[list[float] | None] = [None, None]
    if circle_sigma_px:
        lum_mean = np.nanmean(np.stack([np.nan_to_num(x) for x in lum_full]), axis=0)
        for i, lens in enumerate(prof.lenses):
            cx, cy, rad, inl = fit_image_circle(lum_mean, lens.center, lens.max_radius())
            if math.isfinite(cx) and inl > 0.3 and math.hypot(cx - lens.center[0], cy - lens.center[1]) < 0.1 * lens.max_radius():
                circles[i] = [cx, cy, rad, inl]
                p[3 * i], p[3 * i + 1] = cx - lens.center[0], cy - lens.center[1]
    circle_target = np.array([p[0], p[1], p[3], p[4]])
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
        r0 = residuals(q0, robust_only=True)
        nz = r0[r0 != 0]
        f_scale = max(1.4826 * float(np.median(np.abs(nz - np.median(nz)))) if nz.size else 0.05, 1e-3)
        sol = least_squares(residuals, q0, jac=jacobian, loss="cauchy", f_scale=f_scale, max_nfev=max_nfev, method="trf")
        r1 = residuals(sol.x, robust_only=True)
        p[free] = sol.x * unit
        report.append({
            "downsample": f, "f_scale": f_scale, "nfev": int(sol.nfev), "samples": int(keep.sum()),
            "params": p.tolist(), "status": sol.message,
            "median_abs_residual_before": float(np.median(np.abs(r0[r0 != 0]))) if np.any(r0 != 0) else math.nan,
            "median_abs_residual_after": float(np.median(np.abs(r1[r1 != 0]))) if np.any(r1 != 0) else math.nan,
        })
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

    Returns a summary: parameter changes, per-level residuals, and the seam disagreement
    (median |difference| of the two lenses on the feather band, linear) before and after,
    averaged over the images.
    """
    if not paths:
        raise InputError("no images given")
    prof = load_profile(base)
    images, sat = [], None
    for p in paths:
        img, s = read_linear(Path(p))
        images.append(img)
        sat = s if sat is None else sat
    res = refine_overlap(images, prof, saturation=sat, circle_sigma_px=circle_sigma_px, scale_sigma=scale_sigma,
                         fix_scale=fix_scale)
    h, w = images[0].shape[:2]
    out_h = max(64, min(512, w // 4))

    def seam(profile: LensProfile) -> float:  # what `capture unwarp` reports as seam_mad (after gain matching)
        vals = []
        for img in images:
            maps, _ = get_maps(profile, (w, h), out_h)
            warped = [warp_lens(img.astype(np.float32, copy=False), maps, i) for i in range(len(profile.lenses))]
            vals.append(seam_disagreement(warped, maps, match_gains(warped, maps, sat))["seam_mad"])
        return float(np.mean(vals))

    before, after = seam(prof), seam(res.profile)
    refined = res.profile.model_copy(update={
        "model": f"{prof.model}-unit",
        "parent": prof.model,
        "source": f"refined by solidkit calibrate overlap on {len(paths)} image(s) from the {prof.model!r} profile "
                  f"(whose source: {prof.source})",
        "residuals": {
            "seam_mad_linear_before": before, "seam_mad_linear_after": after,
            "center_shift_px": res.center_shift_px, "scale": res.scale,
            "back_rotation_change_deg": res.rotation_change_deg, "image_circles_px": res.circles,
            "levels": [{k: v for k, v in lv.items() if k != "params"} for lv in res.levels],
        },
        "provenance": make_provenance(paths, tool="solidkit calibrate overlap", circle_sigma_px=circle_sigma_px,
                                      scale_sigma=scale_sigma, fix_scale=fix_scale),
    })
    refined.save(out)
    return {"output": str(out), "base": prof.model, "images": len(paths), "seam_mad_before": before,
            "seam_mad_after": after, "center_shift_px": res.center_shift_px, "scale": res.scale,
            "back_rotation_change_deg": res.rotation_change_deg,
            "back_ypr_deg": list(refined.lenses[1].ypr_deg), "levels": refined.residuals["levels"]}
