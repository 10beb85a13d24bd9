"""Each capture's yaw in the photo's panorama frame, from independent cues (conventions §8).

Cues (degrees; ``yaw_c``: capture level frame -> photo panorama frame, ``d_P = R_y(yaw_c) d_L``):

- ``photo_features`` (camera-position capture only): SIFT between the photo and perspective
  crops of the capture's level panorama; both were taken from one place, so the matched rays
  are related by a rotation ``b = R a`` (:func:`solidkit.align.geometry.estimate_rotation`) and
  ``R = R_y(-yaw_cam) R(0, pitch_photo, roll_photo)``: its yaw gives ``yaw_cam``, its pitch and
  roll check the photo's own.
- ``features``: SIFT between the capture's level panorama and the camera-position capture's,
  related by ``x_c = R_y(yaw_cam - yaw_c) x_cam + t``
  (:func:`solidkit.align.geometry.estimate_level_pose`): ``yaw_c = yaw_cam - psi``.
- ``sun``: the scene's sun (consensus of the other captures, photo panorama frame) minus the
  capture's own sun azimuth (after the ephemeris drift between their times).
- ``compass``: ``heading_c - photo_heading`` (weak: a compass is good to several degrees).
- ``features_via_<id>``, ``manhattan``, ``linked``: fallbacks for captures the cues above leave
  with the compass alone (:mod:`solidkit.align.pipeline`, :mod:`solidkit.align.manhattan`,
  :mod:`solidkit.align.links`, :mod:`solidkit.align.sky`).
- ``label``: a human ``heading`` label; it overrides every cue and is recorded as such.

:func:`fuse_cues` forms the consensus: the weighted circular mean of the cues that agree with
the most precise one within three sigmas (iterated), their RMS residual, and flags for every
disagreeing cue. A cue is never averaged in once it disagrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np

from solidkit.align.features import Features, match_features, rays_from_pixels
from solidkit.align.geometry import LevelPoseFit, estimate_level_pose, estimate_rotation
from solidkit.align.schema import Cue, wrap_deg
from solidkit.envmap.coords import ypr_from_rotation
from solidkit.flags import Flag, FlagCode, disagrees_code

__all__ = ["PhotoMatch", "match_photo", "refine_focal", "feature_cue", "fuse_cues", "Fused"]


@dataclass(frozen=True)
class PhotoMatch:
    """Photo <-> camera-position capture: ``yaw_cam`` and the photo's pitch/roll (degrees)."""

    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    sigma_deg: float
    n_matches: int
    n_inliers: int
    rms_deg: float
    R: np.ndarray
    focal_scale: float = 1.0


def refine_focal(
    pixels: np.ndarray, targets: np.ndarray, K: np.ndarray, *, lo: float = 0.8, hi: float = 1.25
) -> tuple[float, float]:
    """Focal-length scale ``s`` (``fx, fy -> s fx, s fy``) minimising the rotation residual of inlier matches.

    Rotation-only geometry fixes the focal length when the matches spread over the frame: the
    angles between rays must equal the angles between their panorama directions. Golden-section
    search on ``log s`` of the RMS residual after the least-squares rotation
    (:meth:`scipy.spatial.transform.Rotation.align_vectors`). Returns ``(s, rms_rad)``.
    """
    from scipy.optimize import minimize_scalar
    from scipy.spatial.transform import Rotation

    def rms(log_s: float) -> float:
        Ks = K.copy()
        Ks[0, 0] *= math.exp(log_s)
        Ks[1, 1] *= math.exp(log_s)
        a = rays_from_pixels(pixels, Ks)
        rot, _ = Rotation.align_vectors(targets, a)
        d = np.arccos(np.clip(np.sum(rot.apply(a) * targets, axis=1), -1.0, 1.0))
        return float(np.sqrt(np.mean(d**2)))

    res = minimize_scalar(rms, bounds=(math.log(lo), math.log(hi)), method="bounded", options={"xatol": 1e-4})
    return math.exp(float(res.x)), float(res.fun)


def match_photo(
    photo: Features,
    pano: Features,
    *,
    K: np.ndarray | None = None,
    threshold_deg: float = 0.5,
    min_inliers: int = 8,
    refine_f: bool = True,
    min_refine_inliers: int = 12,
    ratio: float = 0.85,
) -> tuple[PhotoMatch | None, str]:
    """Rotation between a photo's rays (camera frame) and a level panorama's directions.

    With ``K`` (the photo's intrinsics, those ``photo``'s rays were made with) and enough inliers,
    the focal length is refined (:func:`refine_focal`) and the rotation re-estimated with it;
    ``PhotoMatch.focal_scale`` reports the factor.
    """
    m = match_features(photo, pano, ratio=ratio)
    if len(m) < min_inliers:
        return None, f"{len(m)} SIFT matches between the photo and the panorama (< {min_inliers})"
    fit = estimate_rotation(
        photo.directions[m[:, 0]],
        pano.directions[m[:, 1]],
        threshold=math.radians(threshold_deg),
        min_inliers=min_inliers,
    )
    if fit is None:
        return None, f"{len(m)} matches, no rotation with {min_inliers}+ inliers"
    scale = 1.0
    loose = (
        estimate_rotation(
            photo.directions[m[:, 0]],
            pano.directions[m[:, 1]],
            threshold=math.radians(3 * threshold_deg),
            min_inliers=min_inliers,
        )
        if refine_f
        else None
    )
    if loose is not None and K is not None and loose.n_inliers >= min_refine_inliers:
        # a focal length a few % off bends the rays by up to ~1 deg at the edges: refine on a loose inlier set
        px, tg = photo.pixels[m[loose.inliers, 0]], pano.directions[m[loose.inliers, 1]]
        scale, _ = refine_focal(px, tg, np.asarray(K, np.float64))
        Ks = np.asarray(K, np.float64).copy()
        Ks[0, 0] *= scale
        Ks[1, 1] *= scale
        refit = estimate_rotation(
            rays_from_pixels(photo.pixels[m[:, 0]], Ks),
            pano.directions[m[:, 1]],
            threshold=math.radians(threshold_deg),
            min_inliers=min_inliers,
        )
        if refit is not None and refit.n_inliers >= fit.n_inliers * 0.9:
            fit = refit
        else:
            scale = 1.0
    yaw, pitch, roll = (math.degrees(float(v)) for v in ypr_from_rotation(fit.R))
    # yaw precision: the RMS ray residual over the inliers' count, floored at a tenth of the threshold
    sigma = max(math.degrees(fit.rms) / math.sqrt(fit.n_inliers), 0.02)
    detail = f"{fit.n_inliers}/{len(m)} matches agree on one rotation (RMS {math.degrees(fit.rms):.2f} deg)"
    if scale != 1.0:
        detail += f"; focal length x{scale:.4f}"
    return PhotoMatch(
        wrap_deg(-yaw), pitch, roll, sigma, len(m), fit.n_inliers, math.degrees(fit.rms), fit.R, scale
    ), detail


def feature_cue(
    cam: Features,
    other: Features,
    yaw_cam_deg: float | None,
    yaw_cam_sigma: float,
    *,
    min_inliers: int = 12,
    level_sigma_deg: float = 0.3,
    max_baseline_elevation_deg: float | None = 60.0,
    ratio: float = 0.85,
    few_inliers: int = 18,
    few_inliers_sigma_deg: float = 2.0,
    reference: str = "the camera position",
) -> tuple[Cue, LevelPoseFit | None]:
    """The ``features`` cue of a capture against the camera-position capture (or the capture ``reference``
    names, whose yaw is ``yaw_cam_deg``); also returns the fit.

    The cue's sigma adds the levelling uncertainty (a tilt error of either panorama biases the
    yaw of off-horizon matches) to the fit's own; a fit from fewer than ``few_inliers`` inliers
    gets at least ``few_inliers_sigma_deg`` (its own sigma is far too optimistic there).
    """
    m = match_features(cam, other, ratio=ratio)
    if len(m) < min_inliers:
        return Cue(yaw_deg=None, ok=False, detail=f"features failed: {len(m)} SIFT matches (< {min_inliers})"), None
    fit = estimate_level_pose(
        cam.directions[m[:, 0]],
        other.directions[m[:, 1]],
        min_inliers=min_inliers,
        max_baseline_elevation=None if max_baseline_elevation_deg is None else math.radians(max_baseline_elevation_deg),
    )
    if fit is None:
        return Cue(
            yaw_deg=None,
            ok=False,
            detail=f"features failed: {len(m)} matches, no relative pose with {min_inliers}+ inliers",
        ), None
    psi = math.degrees(fit.yaw)
    # measured on rendered campaigns: level-pose yaws are 0.1-0.9 deg off with 12-30 inliers, mostly from the two
    # panoramas' residual tilts; the fit's own sigma is far smaller
    own = max(math.degrees(fit.sigma), 0.05)
    if fit.n_inliers < few_inliers:
        # measured on virtual campaigns (seeds 0, 1, 3, 11): level poses from 12-16 inliers were 2.0-2.8 deg off in
        # 4 of 5 cases, from 18+ inliers at most 0.73 deg; the fit's own sigma does not show it
        own = max(own, few_inliers_sigma_deg)
    sigma = math.hypot(own, level_sigma_deg, yaw_cam_sigma)
    yaw = None if yaw_cam_deg is None else wrap_deg(yaw_cam_deg - psi)
    detail = (
        f"{fit.n_inliers}/{len(m)} matches on a level relative pose (RMS {math.degrees(fit.rms):.2f} deg); "
        f"relative yaw to {reference} {wrap_deg(-psi):+.2f} deg"
    )
    if fit.n_inliers < few_inliers:
        detail += f"; few inliers: sigma >= {few_inliers_sigma_deg:g} deg"
    return Cue(yaw_deg=yaw, sigma_deg=sigma, ok=yaw is not None, detail=detail), fit


@dataclass(frozen=True)
class Fused:
    yaw_deg: float | None
    sigma_deg: float | None
    residual_deg: float | None
    flags: list[str]


def fuse_cues(cues: dict[str, Cue], *, n_sigma: float = 3.0, floor_deg: float = 0.3) -> Fused:
    """Consensus of the cues (updated in place: ``ok``, ``weight``, ``residual_deg``); see module doc.

    Two cues agree when they differ by at most ``n_sigma`` times their combined sigma (each
    sigma floored at ``floor_deg``). The seed is the most precise cue that another agrees with
    (else the most precise cue); the consensus is the inverse-variance weighted circular mean of
    the agreeing cues.
    """
    flags: list[str] = []
    usable = {k: c for k, c in cues.items() if c.yaw_deg is not None and c.sigma_deg is not None}
    for k, c in cues.items():
        if k not in usable:
            c.ok, c.weight = False, 0.0
    if not usable:
        return Fused(None, None, None, [str(Flag(FlagCode.NO_YAW, "no cue gave a yaw"))])

    def yaw_of(c: Cue) -> float:  # only usable cues are asked: they have a yaw and a sigma
        return cast(float, c.yaw_deg)

    def sig(c: Cue) -> float:  # for agreement: no cue is trusted below floor_deg
        return max(float(cast(float, c.sigma_deg)), floor_deg)

    def wsig(c: Cue) -> float:  # for weighting: the cue's own precision
        return max(float(cast(float, c.sigma_deg)), 0.02)

    def agree(a: Cue, b: Cue) -> bool:
        return abs(wrap_deg(yaw_of(a) - yaw_of(b))) <= n_sigma * math.hypot(sig(a), sig(b))

    order = sorted(usable, key=lambda k: sig(usable[k]))
    seed = next((k for k in order if any(agree(usable[k], usable[j]) for j in order if j != k)), order[0])
    members = [k for k in order if k == seed or agree(usable[seed], usable[k])]
    yaw = yaw_of(usable[seed])
    for _ in range(3):
        w = np.array([1.0 / wsig(usable[k]) ** 2 for k in members])
        ang = np.radians([yaw_of(usable[k]) for k in members])
        yaw = math.degrees(math.atan2(float(np.sum(w * np.sin(ang))), float(np.sum(w * np.cos(ang)))))
        members = [k for k in order if abs(wrap_deg(yaw_of(usable[k]) - yaw)) <= n_sigma * sig(usable[k])] or [seed]
    w = np.array([1.0 / wsig(usable[k]) ** 2 for k in members])
    sigma = 1.0 / math.sqrt(float(w.sum()))
    res = [wrap_deg(yaw_of(usable[k]) - yaw) for k in members]
    for k, c in usable.items():
        c.residual_deg = wrap_deg(yaw_of(c) - yaw)
        c.ok = k in members
        c.weight = float(1.0 / wsig(c) ** 2 / w.sum()) if c.ok else 0.0
        if not c.ok:
            flags.append(str(Flag(disagrees_code(k), f"{c.residual_deg:+.1f} deg from the consensus")))
    if len(members) == 1 and len(usable) == 1:
        flags.append(str(Flag(FlagCode.SINGLE_CUE, f"yaw from {members[0]} only")))
    elif len(members) == 1:
        flags.append(
            str(Flag(FlagCode.NO_AGREEMENT, f"no two cues agree; the most precise ({members[0]}) is used (review)"))
        )
    # inverse-variance weighted RMS: a compass 5 deg off does not make a 0.1 deg alignment look bad
    rms = float(np.sqrt(np.sum(w * np.square(res)) / np.sum(w))) if len(res) > 1 else None
    return Fused(wrap_deg(yaw), sigma, rms, flags)
