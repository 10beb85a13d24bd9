"""Sun labels that reject glints: every saturated blob is a candidate, physics chooses.

Per capture (:func:`find_candidates`): the low-exposure sun frame (LDR, that capture's level
frame) is thresholded at ``saturation`` on its smallest channel; blobs closer than a couple of
pixels are one candidate (JPEG noise splits a saturated disk); each candidate's direction is the
spherical centroid (:func:`solidkit.envmap.sun.spherical_centroid`) of its saturated core and
its partially covered rim, weighted by how far each pixel rises above the rim level.

Per scene (:func:`choose_sun`, one function per step), the tests a glint fails (a mirror image of the sun in glass is
as bright and as small as the sun, so brightness and confidence cannot tell them apart):

1. **Size**: the sun's disk is 0.53° wide; a saturated core wider than ``max_size_deg`` is a
   bright surface or cloud. Within a scene (one exposure, minutes apart) the sun's core keeps its
   size (within 20 % on virtual campaigns); a candidate accepted without a yaw (elevation only)
   that is ``max_size_ratio`` times wider than the winning hypothesis' is a glint (1.3-2x measured;
   only when the winner's core is at least the disk's 0.53°: a narrower one is a partly hidden sun),
   and so is one ``wide_size_ratio`` times wider that lies more than two compass sigmas from
   where the compass and the ephemeris put the sun.
2. **Sky, not facade**: in the capture's normal exposure (HDR or LDR panorama) the ring 1.5-6°
   around the candidate must be mostly sky-bright (a glint sits on a dark facade).
3. **Same world direction everywhere**: the sun is at infinity, so once each capture is turned
   into the photo's panorama frame by its yaw (features, compass), all positions see it in one
   direction (after the ephemeris drift between their times, when the sun moves); a glint
   moves with the viewpoint and is seen from few positions. Elevations agree without any yaw.
4. **Ephemeris**: pvlib's apparent elevation at each capture's own time and GPS must match the
   candidate's elevation (exactly, up to levelling); its azimuth minus the compass heading
   must match within the compass's error.

Hypotheses are the candidates' directions in the photo's panorama frame; each is scored by the
captures that have a candidate agreeing with it, each weighed by how sun-like that candidate is
(:meth:`SunScene.sun_likeness`: its width against the scene's narrowest whole core, the 0.53° disk
widened by the optics, and its shape), and by the ephemeris through the photo's compass (up to
3.5 captures' worth: a plane mirror's image of the sun is one world direction from every position
that sees it, so agreeing positions alone cannot tell it from the sun). Where the elevation matches
the ephemeris (clock and GPS right) and the captures' compasses agree with their feature yaws (the
photo's heading right), a candidate more than three compass sigmas from the ephemeris' azimuth is
rejected. The best wins, and every other candidate is rejected with the reasons it failed. A scene
whose images agree with each other but not with the ephemeris is flagged, never averaged with it,
and so is every capture whose chosen sun is off the ephemeris (``sun_off_ephemeris``), each flag
naming the likelier cause (:func:`likelier_cause`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple, cast

import cv2
import numpy as np

from solidkit.align.ephemeris import at_photo_time
from solidkit.align.schema import (
    CaptureSun,
    Ephemeris,
    SceneSun,
    SunCandidate,
    photo_azimuth_from_solar,
    solar_azimuth_from_photo,
    wrap_deg,
)
from solidkit.envmap.coords import (
    angles_from_direction,
    angular_distance,
    coords_from_direction,
    direction_from_angles,
    direction_grid,
    solid_angle,
)
from solidkit.envmap.sun import SUN_ANGULAR_DIAMETER, label_spherical, luminance, spherical_centroid
from solidkit.flags import Flag, FlagCode

__all__ = [
    "Blob",
    "SunSettings",
    "CaptureSunInput",
    "find_candidates",
    "sky_fraction",
    "scene_sun",
    "choose_sun",
    "SunChoice",
    "SunScene",
    "PhotoDirection",
    "Agreement",
    "Hypothesis",
    "Rejections",
    "likelier_cause",
    "hard_rejections",
    "best_hypothesis",
    "choose_candidates",
    "capture_results",
    "with_human_labels",
    "consensus",
]


@dataclass(frozen=True)
class Blob:
    """A saturated blob of a sun frame; angles in degrees in the capture's level frame.

    ``size_deg``: the diameter of a disk of the saturated core's solid angle; ``elongation``: the ratio of
    the core's long to short axis (>= 1; a disk: 1); ``core_fraction``: the saturated core's share of the
    blob's solid angle above the rim level (a sun's hard edge: most of it; a glint's soft falloff: less);
    ``pixel_deg``: the sun frame's pixel (180 / H).
    """

    direction: np.ndarray
    azimuth_deg: float
    elevation_deg: float
    size_deg: float
    n_pixels: int
    contrast: float
    sky_fraction: float | None = None
    elongation: float = 1.0
    core_fraction: float = 1.0
    pixel_deg: float = 0.0


@dataclass(frozen=True)
class SunSettings:
    """Tolerances of the sun choice (degrees unless named otherwise)."""

    saturation: float = 0.9
    max_size_deg: float = 3.0
    max_size_ratio: float = 1.35
    wide_size_ratio: float = 1.2
    min_sky_fraction: float = 0.35
    level_sigma_deg: float = 0.4
    centroid_sigma_deg: float = 0.1
    compass_sigma_deg: float = 8.0
    sun_moves: bool = True
    ephemeris_tolerance_deg: float = 1.5
    max_candidates: int = 12
    size_slack: float = 1.25
    size_log_sigma: float = 0.25
    max_elongation: float = 2.0
    min_shape_pixels: int = 20
    ephemeris_azimuth_weight: float = 3.5
    compass_azimuth_weight: float = 1.0


@dataclass
class CaptureSunInput:
    """What the scene-level choice knows about one capture."""

    probe: str
    blobs: list[Blob]
    ephemeris: Ephemeris | None = None
    yaw_deg: float | None = None
    yaw_sigma_deg: float | None = None
    heading_deg: float | None = None
    note: str = ""
    human: CaptureSun | None = None
    extra_flags: list[str] = field(default_factory=list)
    compass_yaw_deg: float | None = None  # only breaks ties between candidates (a compass can be 90 deg off)


# --------------------------------------------------------------------------- per capture
def find_candidates(
    sun_frame: np.ndarray, *, saturation: float = 0.9, merge_px: int = 2, max_candidates: int = 12
) -> list[Blob]:
    """Saturated blobs of an LDR sun frame ``(H, 2H, 3)`` (encoded values in ``[0, 1]``), largest first.

    The rim level is ``saturation - 0.4``: rim pixels between it and ``saturation`` weigh
    linearly less. ``contrast`` is the core level over the median of the ring 2-6° around it.
    """
    img = np.asarray(sun_frame, np.float32)
    if img.dtype == np.uint8:
        img = img / 255.0
    lo = img[..., :3].min(axis=2) if img.ndim == 3 else img
    h = lo.shape[0]
    sat = lo >= saturation
    if not sat.any():
        return []
    kernel = np.ones((2 * merge_px + 1, 2 * merge_px + 1), np.uint8)
    grown = cv2.dilate(sat.astype(np.uint8), kernel) > 0
    labels, n = label_spherical(grown)
    rim_level = saturation - 0.4
    weights = np.clip((lo - rim_level) / (saturation - rim_level), 0.0, 1.0)
    omega = solid_angle(h)
    areas = np.bincount(labels[sat], weights=omega[sat], minlength=n + 1)
    order = np.argsort(-areas[1:])[:max_candidates] + 1
    blobs = []
    px = math.degrees(math.pi / h)
    for k in order:
        comp = labels == k
        core = comp & sat
        if not core.any():
            continue
        d = spherical_centroid(weights, comp & (lo > rim_level))
        if d is None:
            continue
        az, el = (math.degrees(float(v)) for v in angles_from_direction(d))
        size = math.degrees(2.0 * math.sqrt(float(areas[k]) / math.pi))
        ring = _ring(h, d, max(2.0, 3 * px), 6.0)
        bg = float(np.median(lo[ring])) if ring.any() else 0.0
        lit = comp & (lo > rim_level)
        core_fraction = float(areas[k]) / max(float(omega[lit].sum()), 1e-12)
        blobs.append(
            Blob(
                d,
                wrap_deg(az),
                el,
                size,
                int(core.sum()),
                float(saturation / max(bg, 1e-3)),
                elongation=_elongation(core, omega, d, h),
                core_fraction=min(core_fraction, 1.0),
                pixel_deg=px,
            )
        )
    return blobs


def _elongation(core: np.ndarray, omega: np.ndarray, d: np.ndarray, h: int) -> float:
    """Long over short axis of a blob's core ``(H, 2H)`` bool about its direction ``d``: the square root of its
    second moments' eigenvalue ratio in the plane tangent to the sphere at ``d`` (a pixel's own extent included)."""
    ys, xs = np.nonzero(core)
    rays = direction_grid(h)[ys, xs]
    e1 = np.cross(d, [0.0, -1.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    uv = np.stack([rays @ e1, rays @ e2], axis=1)
    w = omega[ys, xs]
    mean = (w[:, None] * uv).sum(axis=0) / w.sum()
    c = ((uv - mean) * w[:, None]).T @ (uv - mean) / w.sum()
    pix = (math.pi / h) ** 2 / 12.0  # a pixel's own second moment
    lo, hi = np.linalg.eigvalsh(c)
    return float(math.sqrt((hi + pix) / (max(lo, 0.0) + pix)))


def _ring(h: int, d: np.ndarray, inner_deg: float, outer_deg: float) -> np.ndarray:
    """Pixels whose direction is ``inner..outer`` degrees from ``d`` (``(H, 2H)`` bool), computed in a window."""
    x, y = (float(v) for v in coords_from_direction(d, h))
    r_px = outer_deg / (180.0 / h) + 2
    el = math.asin(max(-1.0, min(1.0, -float(d[1]))))
    span_x = r_px / max(math.cos(el), 0.05)
    y0, y1 = max(0, int(y - r_px)), min(h, int(y + r_px) + 1)
    mask = np.zeros((h, 2 * h), bool)
    grid = direction_grid(h)
    if span_x >= h:
        cols = np.arange(2 * h)
    else:
        cols = np.arange(int(x - span_x), int(x + span_x) + 1) % (2 * h)
    sub = grid[y0:y1][:, cols] @ d
    sel = (sub <= math.cos(math.radians(inner_deg))) & (sub >= math.cos(math.radians(outer_deg)))
    block = np.zeros((y1 - y0, len(cols)), bool) | sel
    mask[y0:y1, cols] = block
    return mask


def sky_fraction(
    normal_pano: np.ndarray,
    direction: np.ndarray,
    *,
    inner_deg: float = 1.5,
    outer_deg: float = 6.0,
    exclude: list[np.ndarray] | None = None,
) -> float:
    """Fraction of the ring around ``direction`` that is sky-bright in a normal-exposure panorama.

    ``normal_pano``: linear ``(H, 2H, 3)`` (HDR or decoded LDR), same level frame as the sun
    frame. The sky level is the 90th percentile (solid-angle weighted) of the luminance above
    10° elevation outside 8° caps about ``direction`` and ``exclude``; a ring pixel is sky-bright
    at half that level or above.
    """
    lum = luminance(np.asarray(normal_pano, np.float32))
    h = lum.shape[0]
    if h > 512:  # a smooth statistic: area-averaged copy
        lum = cv2.resize(lum, (1024, 512), interpolation=cv2.INTER_AREA)
        h = 512
    grid = direction_grid(h)
    upper = -grid[..., 1] >= math.sin(math.radians(10.0))
    for e in [direction, *(exclude or [])]:
        upper &= grid @ e < math.cos(math.radians(8.0))
    if not upper.any():
        return 0.0
    w = np.broadcast_to(solid_angle(h), lum.shape)[upper]
    vals = lum[upper]
    order = np.argsort(vals)
    cdf = np.cumsum(w[order]) / w.sum()
    sky = float(vals[order][min(np.searchsorted(cdf, 0.9), len(vals) - 1)])
    ring = _ring(h, direction, inner_deg, outer_deg)
    if not ring.any() or sky <= 0:
        return 0.0
    return float(np.mean(lum[ring] >= 0.5 * sky))


# --------------------------------------------------------------------------- per scene
class PhotoDirection(NamedTuple):
    """A sun direction in the photo's panorama frame at the photo's time; degrees. ``azimuth_deg`` is
    ``None`` where no yaw ties the capture it was seen from to the photo (the elevation needs none)."""

    azimuth_deg: float | None
    elevation_deg: float


@dataclass(frozen=True)
class Agreement:
    """Whether a candidate agrees with a hypothesis of the sun (:meth:`SunScene.agrees`), and why.

    ``elevation_only``: it agrees on elevation and its capture's yaw (or the hypothesis') is unknown,
    so the azimuth was not tested.
    """

    ok: bool
    why: str
    elevation_only: bool = False


@dataclass(frozen=True)
class Hypothesis:
    """The sun where candidate ``bi`` of capture ``ci`` is (:func:`best_hypothesis`), in the photo's
    panorama frame at the photo's time; ``members``: the candidate of every capture that agrees with it
    (``{capture index: candidate index}``); ``score``: supporting captures, each by its candidate's
    sun-likeness (half for an agreement on elevation only), plus the ephemeris' elevation test (1.5) and its
    azimuth vote (:meth:`SunScene.ephemeris_azimuth_score`), plus a contrast tie-break."""

    score: float
    ci: int
    bi: int
    azimuth_deg: float | None
    elevation_deg: float
    members: dict[int, int]
    ephemeris_elevation_ok: bool
    ephemeris_azimuth_ok: bool


#: Rejection reasons of each candidate, ``{(capture index, candidate index): [reason, ...]}``
#: (empty: not rejected).
Rejections = dict[tuple[int, int], list[str]]


@dataclass(frozen=True)
class SunScene:
    """What every stage of :func:`choose_sun` reads: the scene's captures, the photo's ephemeris and
    compass heading, the settings, and what follows from them."""

    captures: list[CaptureSunInput]
    photo_ephemeris: Ephemeris | None
    photo_heading_deg: float | None
    settings: SunSettings

    @cached_property
    def el_tol(self) -> float:
        """Elevation tolerance (degrees): three sigmas of levelling and centroid, plus 0.1."""
        s = self.settings
        return 3.0 * math.hypot(s.level_sigma_deg, s.centroid_sigma_deg) + 0.1

    @cached_property
    def reference_size_deg(self) -> float:
        """The width a whole sun's core has in this scene (degrees): the narrowest candidate at least the disk's
        0.53 deg wide (one exposure, minutes apart: one size; a narrower core is a partly hidden sun), and no less
        than the disk widened by the optics (two sun-frame pixels)."""
        s = self.settings
        disk = math.degrees(SUN_ANGULAR_DIAMETER)
        whole = [
            b.size_deg
            for c in self.captures
            for b in c.blobs
            if disk <= b.size_deg <= s.max_size_deg and (b.sky_fraction is None or b.sky_fraction >= s.min_sky_fraction)
        ]
        optics = max((math.hypot(disk, 2.0 * b.pixel_deg) for c in self.captures for b in c.blobs), default=disk)
        return max(min(whole, default=optics), optics)

    def sun_likeness(self, ci: int, bi: int) -> tuple[float, str]:
        """How sun-like candidate ``bi`` of capture ``ci`` is on its own, in ``(0, 1]``, and why it is less: its
        width against :attr:`reference_size_deg` (up to ``size_slack`` wider is the same sun; beyond, a Gaussian
        in the log of the ratio with ``size_log_sigma``) and its shape (a core of ``min_shape_pixels`` or more
        with a long axis ``max_elongation`` times its short one or more is a streak, not a disk)."""
        s, b = self.settings, self.captures[ci].blobs[bi]
        ref = self.reference_size_deg
        chi2, why = 0.0, []
        excess = math.log(max(b.size_deg, 1e-6) / (s.size_slack * ref))
        if excess > 0:
            chi2 += (excess / s.size_log_sigma) ** 2
            why.append(f"{b.size_deg:.2f} deg wide vs {ref:.2f} deg for the sun here")
        if b.n_pixels >= s.min_shape_pixels and b.elongation > s.max_elongation:
            chi2 += ((b.elongation - s.max_elongation) / 0.4) ** 2
            why.append(f"elongated {b.elongation:.1f}:1")
        return math.exp(-0.5 * chi2), "; ".join(why)

    def ephemeris_azimuth_score(self, ci: int, bi: int, h_az: float | None) -> float:
        """The ephemeris' vote for candidate ``bi`` of capture ``ci`` at photo-frame azimuth ``h_az``: up to
        ``ephemeris_azimuth_weight`` where the ephemeris through the photo's compass puts the sun (a Gaussian in
        azimuth with ``compass_sigma_deg``); without a yaw, up to ``compass_azimuth_weight`` through the
        capture's own compass (wider: a compass can be 90 deg off)."""
        s, eph_p, cap = self.settings, self.ephemeris_in_photo, self.captures[ci]
        if eph_p is None or eph_p.azimuth_deg is None:
            return 0.0
        if h_az is not None:
            d = wrap_deg(h_az - eph_p.azimuth_deg)
            return s.ephemeris_azimuth_weight * math.exp(-0.5 * (d / s.compass_sigma_deg) ** 2)
        if cap.compass_yaw_deg is not None:
            d = wrap_deg(self.compass_azimuth(ci, bi) - eph_p.azimuth_deg)
            return s.compass_azimuth_weight * math.exp(-0.5 * (d / (1.5 * s.compass_sigma_deg)) ** 2)
        return 0.0

    @cached_property
    def compasses_agree(self) -> bool | None:
        """Whether the captures' compasses agree with their yaws from other cues (features): most within three
        compass sigmas (None: no capture has both). Then the photo's compass heading is right, the ephemeris'
        azimuth in the photo frame too unless the clock or GPS is wrong (the elevation tells)."""
        s = self.settings
        pairs = [
            abs(wrap_deg(c.yaw_deg - c.compass_yaw_deg))
            for c in self.captures
            if c.yaw_deg is not None and c.compass_yaw_deg is not None
        ]
        if not pairs:
            return None
        return sum(d <= 3.0 * s.compass_sigma_deg for d in pairs) * 2 > len(pairs)

    @cached_property
    def ephemeris_in_photo(self) -> PhotoDirection | None:
        """pvlib's sun at the photo's time in its panorama frame (azimuth through the photo's compass)."""
        eph = self.photo_ephemeris
        if eph is None:
            return None
        heading = self.photo_heading_deg
        az = None if heading is None else photo_azimuth_from_solar(eph.azimuth_deg, heading)
        return PhotoDirection(az, eph.elevation_deg)

    def at_photo_time(self, ci: int, bi: int) -> tuple[float, float]:
        """(azimuth, elevation) of candidate ``bi`` of capture ``ci`` in that capture's level frame, at the photo's
        time."""
        cap = self.captures[ci]
        b = cap.blobs[bi]
        return at_photo_time(
            b.azimuth_deg, b.elevation_deg, cap.ephemeris, self.photo_ephemeris, sun_moves=self.settings.sun_moves
        )

    def in_photo_frame(self, ci: int, bi: int) -> PhotoDirection:
        """Candidate ``bi`` of capture ``ci`` in the photo's panorama frame at the photo's time (the capture's yaw)."""
        cap = self.captures[ci]
        az, el = self.at_photo_time(ci, bi)
        return PhotoDirection(None if cap.yaw_deg is None else wrap_deg(az + cap.yaw_deg), el)

    def compass_azimuth(self, ci: int, bi: int) -> float:
        """Azimuth of candidate ``bi`` of capture ``ci`` in the photo's panorama frame through the capture's
        compass yaw (unwrapped; the caller checks ``compass_yaw_deg`` is known)."""
        az, _ = self.at_photo_time(ci, bi)
        compass_yaw_deg = self.captures[ci].compass_yaw_deg
        assert compass_yaw_deg is not None  # checked by the caller
        return az + compass_yaw_deg

    def agrees(self, h_az: float | None, h_el: float, h_sig: float, ci: int, bi: int) -> Agreement:
        """Candidate ``bi`` of capture ``ci`` against a hypothesis at ``(h_az, h_el)`` whose capture's yaw
        has sigma ``h_sig``: elevation within :attr:`el_tol`, azimuth (when both yaws are known) within
        three sigmas of both yaws plus the elevation tolerance at that elevation."""
        cap = self.captures[ci]
        az, el = self.in_photo_frame(ci, bi)
        el_tol = self.el_tol
        if abs(el - h_el) > el_tol:
            return Agreement(False, f"elevation {el:.2f} deg vs {h_el:.2f} deg")
        if h_az is None or az is None:
            return Agreement(True, "elevation only (yaw unknown)", elevation_only=True)
        tol = 3.0 * math.hypot(h_sig, cap.yaw_sigma_deg or 0.0) + el_tol / max(math.cos(math.radians(h_el)), 0.2)
        d = abs(wrap_deg(az - h_az))
        return Agreement(d <= tol, f"azimuth {az:.2f} deg vs {h_az:.2f} deg (tolerance {tol:.1f})")


def hard_rejections(captures: list[CaptureSunInput], settings: SunSettings) -> Rejections:
    """Step 1 (module doc): the tests a candidate fails on its own (size, sky, horizon)."""
    s = settings
    hard: Rejections = {}
    for ci, cap in enumerate(captures):
        for bi, b in enumerate(cap.blobs):
            r = []
            if b.size_deg > s.max_size_deg:
                r.append(
                    f"too large for the sun: {b.size_deg:.2f} deg > {s.max_size_deg:g} deg (a bright surface or cloud)"
                )
            if b.sky_fraction is not None and b.sky_fraction < s.min_sky_fraction:
                r.append(
                    f"not in the sky: only {100 * b.sky_fraction:.0f}% of the ring around it is sky-bright "
                    "(a glint on a facade?)"
                )
            if b.elevation_deg < -2.0:
                r.append(f"below the horizon ({b.elevation_deg:.1f} deg)")
            hard[ci, bi] = r
    return hard


def best_hypothesis(scene: SunScene, hard: Rejections) -> tuple[Hypothesis | None, Rejections]:
    """Step 2: every candidate that passed :func:`hard_rejections` is a hypothesis, scored by the captures
    that agree with it and by the ephemeris; returns the best one and the rejections, with candidates seen
    from one position only and away from the ephemeris (through the compass) rejected as glints. A
    candidate rejected so no longer supports the hypotheses scored after it."""
    s, captures, eph_p = scene.settings, scene.captures, scene.ephemeris_in_photo
    hard = {k: list(v) for k, v in hard.items()}
    best = None
    for ci, cap in enumerate(captures):
        for bi, _ in enumerate(cap.blobs):
            if hard[ci, bi]:
                continue
            h_az, h_el = scene.in_photo_frame(ci, bi)
            h_sig = cap.yaw_sigma_deg or 0.0
            support, members = scene.sun_likeness(ci, bi)[0], {ci: bi}
            for cj, other in enumerate(captures):
                if cj == ci:
                    continue
                fits = [
                    (bj, scene.agrees(h_az, h_el, h_sig, cj, bj)) for bj in range(len(other.blobs)) if not hard[cj, bj]
                ]
                fits = [(bj, a) for bj, a in fits if a.ok]
                if fits:
                    # each supporting capture by how sun-like its candidate is (a mirror image in glass agrees
                    # with the others like the sun, but is wider)
                    votes = [((0.5 if a.elevation_only else 1.0) * scene.sun_likeness(cj, bj)[0], bj) for bj, a in fits]
                    vote, bj = max(votes)
                    support += vote
                    members[cj] = bj
            eph_el_ok = eph_p is not None and abs(h_el - eph_p.elevation_deg) <= s.ephemeris_tolerance_deg
            eph_az_ok = (
                eph_p is not None
                and eph_p.azimuth_deg is not None
                and h_az is not None
                and abs(wrap_deg(h_az - eph_p.azimuth_deg)) <= 3.0 * s.compass_sigma_deg
            )
            if h_az is None and eph_p is not None and eph_p.azimuth_deg is not None and cap.compass_yaw_deg is not None:
                # no yaw but the capture's compass: a tie-breaker only (never a rejection: a compass can be 90 deg off)
                eph_az_ok = (
                    abs(wrap_deg(scene.compass_azimuth(ci, bi) - eph_p.azimuth_deg)) <= 3.0 * s.compass_sigma_deg
                )
            eph_az_bad = eph_p is not None and eph_p.azimuth_deg is not None and h_az is not None and not eph_az_ok
            if eph_az_bad and eph_el_ok and scene.compasses_agree:
                # the clock and GPS are right (the elevation) and the photo's compass too (the captures'
                # compasses agree with their feature yaws): the ephemeris' azimuth stands, whatever agrees here
                assert h_az is not None and eph_p is not None and eph_p.azimuth_deg is not None  # eph_az_bad
                hard[ci, bi] = [
                    f"{abs(wrap_deg(h_az - eph_p.azimuth_deg)):.1f} deg in azimuth from the ephemeris, whose elevation "
                    "it has, while the compasses agree with the feature yaws: a mirror image of the sun in glass?"
                ]
                continue
            if len(members) == 1 and eph_az_bad:
                # seen from one position only and not where the ephemeris and the compass put the sun:
                # nothing confirms it (a glint in a vertical glass wall has the sun's elevation too)
                assert h_az is not None and eph_p is not None and eph_p.azimuth_deg is not None  # eph_az_bad
                off = abs(wrap_deg(h_az - eph_p.azimuth_deg))
                hard[ci, bi] = [
                    f"seen from this position only and {off:.1f} deg in azimuth "
                    "from the ephemeris (through the photo's compass): a glint? (occluded sun elsewhere)"
                ]
                continue
            score = (
                support
                + 1.5 * eph_el_ok
                + scene.ephemeris_azimuth_score(ci, bi, h_az)
                + 0.01 * min(cap.blobs[bi].contrast, 50) / 50
            )
            if best is None or score > best.score:
                best = Hypothesis(score, ci, bi, h_az, h_el, members, eph_el_ok, eph_az_ok)
    return best, hard


def _closeness(scene: SunScene, best: Hypothesis, ci: int, bi: int) -> float:
    """Chi-square of a candidate against the hypothesis: elevation, and azimuth through this capture's
    yaw (features) or, failing that, its compass (a glint in a vertical glass wall has the sun's
    elevation: only the azimuth tells them apart)."""
    s, cap, eph_p = scene.settings, scene.captures[ci], scene.ephemeris_in_photo
    h_az, h_el, el_tol = best.azimuth_deg, best.elevation_deg, scene.el_tol
    az, el = scene.in_photo_frame(ci, bi)
    chi2 = ((el - h_el) / (el_tol / 3.0)) ** 2
    cos_el = max(math.cos(math.radians(h_el)), 0.2)
    if h_az is None and eph_p is not None and eph_p.azimuth_deg is not None and cap.compass_yaw_deg is not None:
        # no capture has a yaw: the ephemeris through the compasses ranks them
        return chi2 + (wrap_deg(scene.compass_azimuth(ci, bi) - eph_p.azimuth_deg) / s.compass_sigma_deg) ** 2
    if h_az is None:
        return chi2
    if az is not None:
        return chi2 + (wrap_deg(az - h_az) * cos_el / math.hypot(cap.yaw_sigma_deg or 0.0, el_tol / 3.0)) ** 2
    if cap.compass_yaw_deg is not None:
        return chi2 + (wrap_deg(scene.compass_azimuth(ci, bi) - h_az) / s.compass_sigma_deg) ** 2
    return chi2


def choose_candidates(scene: SunScene, best: Hypothesis | None, hard: Rejections) -> tuple[dict[int, int], Rejections]:
    """Step 3: per capture, the candidate closest to the best hypothesis that agrees with it
    (``{capture index: candidate index}``), and the rejections, with candidates accepted on elevation
    alone but wider than the hypothesis' core (module doc, test 1) rejected as glints."""
    s, captures, eph_p = scene.settings, scene.captures, scene.ephemeris_in_photo
    hard = {k: list(v) for k, v in hard.items()}
    chosen: dict[int, int] = {}
    if best is None:
        return chosen, hard
    ci0, bi0, h_az, h_el = best.ci, best.bi, best.azimuth_deg, best.elevation_deg
    h_sig = captures[ci0].yaw_sigma_deg or 0.0
    ref_size = captures[ci0].blobs[bi0].size_deg
    for ci, cap in enumerate(captures):
        cands = sorted(
            (bi for bi in range(len(cap.blobs)) if not hard[ci, bi]), key=lambda bi: _closeness(scene, best, ci, bi)
        )
        for bi in cands:
            ok = scene.agrees(h_az, h_el, h_sig, ci, bi).ok
            if ok and ci != ci0 and (h_az is None or cap.yaw_deg is None):
                # accepted on elevation alone, but the sun's saturated core has one size in one scene (same
                # exposure, minutes apart: within 20 % measured); a glint on glass spreads (1.3-2x measured).
                # Somewhat wider AND far from where the compass puts the sun: both weak signs together
                ratio = cap.blobs[bi].size_deg / max(ref_size, 1e-6)
                ref_az = h_az if h_az is not None else (eph_p.azimuth_deg if eph_p is not None else None)
                off = None
                if ref_az is not None and cap.compass_yaw_deg is not None:
                    off = abs(wrap_deg(scene.compass_azimuth(ci, bi) - ref_az))
                # a reference core narrower than the sun's disk is a partly hidden sun (or a small glint):
                # no measure of the sun's size (the shipped mini campaign's scene03: a 0.23 deg core at p01
                # made the camera position's unhidden 0.9 deg sun a "glint")
                sized = ref_size >= math.degrees(SUN_ANGULAR_DIAMETER)
                if sized and (
                    ratio > s.max_size_ratio
                    or (ratio > s.wide_size_ratio and off is not None and off > 2.0 * s.compass_sigma_deg)
                ):
                    hard[ci, bi] = [
                        f"larger than the sun seen from {captures[ci0].probe}: "
                        f"{cap.blobs[bi].size_deg:.2f} deg vs {ref_size:.2f} deg wide"
                        + ("" if off is None else f", {off:.0f} deg from where the compass puts the sun")
                        + " (a glint on glass?)"
                    ]
                    continue
                twin = None
                if off is not None and off > 3.0 * s.compass_sigma_deg:
                    assert ref_az is not None  # off is measured from it
                    twin = _mirror_twin(scene, ci, bi, ref_az, h_el, hard)
                if twin is not None:
                    # one compass 90 deg off is possible; two putting their candidates at one wrong place is not
                    hard[ci, bi] = [
                        f"{off:.0f} deg from where the compass puts the sun, at the sun's elevation, where {twin} "
                        "sees a candidate through its own compass too: a mirror image of the sun in glass"
                    ]
                    continue
            if ok:
                chosen[ci] = bi
                break
    return chosen, hard


def _mirror_twin(scene: SunScene, ci: int, bi: int, ref_az: float, h_el: float, hard: Rejections) -> str | None:
    """Another capture that sees a candidate where candidate ``bi`` of capture ``ci`` is, through the compass,
    at the sun's elevation ``h_el`` and more than three compass sigmas from where the sun is (``ref_az``, the
    photo's frame): the same mirror image of the sun seen from two positions (a plane mirror's image is one
    world direction). Its id, or None. The other capture's azimuth is through its yaw where known, else its
    compass; they agree within twice the compass sigma, times sqrt 2."""
    s, caps = scene.settings, scene.captures
    az_i = scene.compass_azimuth(ci, bi)
    tol = 2.0 * math.sqrt(2.0) * s.compass_sigma_deg
    for cj, other in enumerate(caps):
        if cj == ci:
            continue
        for bj in range(len(other.blobs)):
            if any(r.startswith(("too large", "not in the sky", "below the horizon")) for r in hard.get((cj, bj), [])):
                continue  # no image of the sun at all
            az_j, el_j = scene.in_photo_frame(cj, bj)
            if az_j is None:
                if other.compass_yaw_deg is None:
                    continue
                az_j = scene.compass_azimuth(cj, bj)
            if abs(el_j - h_el) > scene.el_tol or abs(wrap_deg(az_j - ref_az)) <= 3.0 * s.compass_sigma_deg:
                continue
            if abs(wrap_deg(az_j - az_i)) <= tol:
                return other.probe
    return None


def capture_results(
    scene: SunScene, best: Hypothesis | None, hard: Rejections, chosen: dict[int, int]
) -> tuple[list[CaptureSun], set[tuple[int, int]]]:
    """Step 4: one :class:`CaptureSun` per capture, its chosen candidate and every rejected one with its
    reasons; also the candidates that passed every test but another one fitted better (``{(capture
    index, candidate index)}``: their capture's yaw was unknown, so their azimuth was not tested)."""
    s, captures = scene.settings, scene.captures
    results: list[CaptureSun] = []
    outranked: set[tuple[int, int]] = set()
    for ci, cap in enumerate(captures):
        cands = []
        for bi, b in enumerate(cap.blobs):
            reasons = list(hard[ci, bi])
            scores: dict[str, float] = {}
            if cap.ephemeris is not None:
                scores["ephemeris_elevation_deg"] = cap.ephemeris.elevation_deg
                scores["elevation_error_deg"] = b.elevation_deg - cap.ephemeris.elevation_deg
            if b.sky_fraction is not None:
                scores["sky_fraction"] = b.sky_fraction
            if not reasons and chosen.get(ci) != bi:
                if best is None:
                    reasons.append("no consistent sun in the scene")
                else:
                    a = scene.agrees(
                        best.azimuth_deg, best.elevation_deg, captures[best.ci].yaw_sigma_deg or 0.0, ci, bi
                    )
                    if not a.ok:
                        reasons.append(f"disagrees with the scene's sun: {a.why}")
                    else:
                        reasons.append("another candidate fits better")
                        outranked.add((ci, bi))
            cands.append(
                SunCandidate(
                    azimuth_deg=b.azimuth_deg,
                    elevation_deg=b.elevation_deg,
                    size_deg=b.size_deg,
                    n_pixels=b.n_pixels,
                    contrast=b.contrast,
                    chosen=chosen.get(ci) == bi,
                    reasons=reasons,
                    scores=scores,
                )
            )
        flags = list(cap.extra_flags)
        if ci in chosen:
            b = cap.blobs[chosen[ci]]
            unc = math.hypot(s.centroid_sigma_deg, 0.15 * b.size_deg)
            reason = f"sun: {b.n_pixels} saturated px, {b.size_deg:.2f} deg wide"
            if cap.ephemeris is not None:
                reason += f"; elevation {b.elevation_deg - cap.ephemeris.elevation_deg:+.2f} deg from the ephemeris"
            results.append(
                CaptureSun(
                    probe=cap.probe,
                    found=True,
                    azimuth_deg=b.azimuth_deg,
                    elevation_deg=b.elevation_deg,
                    uncertainty_deg=unc,
                    reason=reason,
                    candidates=cands,
                    ephemeris=cap.ephemeris,
                    flags=flags,
                )
            )
        else:
            if not cap.blobs:
                reason = cap.note or "no saturated pixel: sun occluded or overcast"
            elif best is None:
                reason = "no candidate passes the size and sky tests"
            else:
                reason = "no candidate agrees with the scene's sun: occluded here (the others are glints or surfaces)"
            if cap.blobs and best is not None:
                flags.append(FlagCode.SUN_CANDIDATES_REJECTED.value)
            results.append(
                CaptureSun(
                    probe=cap.probe, found=False, reason=reason, candidates=cands, ephemeris=cap.ephemeris, flags=flags
                )
            )
    return results, outranked


def with_human_labels(scene: SunScene, results: list[CaptureSun]) -> list[CaptureSun]:
    """Step 5: a capture's human sun label replaces its automatic choice (keeping the candidates; flagged
    ``auto_differs`` more than 1 deg from it)."""
    out = list(results)
    for ci, cap in enumerate(scene.captures):
        if cap.human is not None:
            auto = out[ci]
            human = cap.human.model_copy(update={"candidates": auto.candidates, "ephemeris": cap.ephemeris})
            if auto.found and human.found:
                assert auto.azimuth_deg is not None and auto.elevation_deg is not None  # a found sun has both
                assert human.azimuth_deg is not None and human.elevation_deg is not None
                d = _angle_deg(auto.azimuth_deg, auto.elevation_deg, human.azimuth_deg, human.elevation_deg)
                if d > 1.0:
                    human.flags = [
                        *human.flags,
                        str(Flag(FlagCode.AUTO_DIFFERS, f"{d:.2f} deg from the automatic choice")),
                    ]
            out[ci] = human
    return out


def consensus(scene: SunScene, results: list[CaptureSun]) -> SceneSun:
    """Step 6: the scene's sun from every capture that found it, in the photo's panorama frame at the
    photo's time (yaws from non-sun cues), elevation and azimuth inverse-variance weighted; each capture
    that disagrees with it flagged, then the ephemeris and the number of positions checked."""
    s, captures = scene.settings, scene.captures
    photo_ephemeris, photo_heading_deg = scene.photo_ephemeris, scene.photo_heading_deg
    el_tol, eph_p = scene.el_tol, scene.ephemeris_in_photo
    scene_flags: list[str] = []
    pts = []
    level_az: dict[int, float] = {}
    for ci, (cap, res) in enumerate(zip(captures, results)):
        if not res.found:
            continue
        assert res.azimuth_deg is not None and res.elevation_deg is not None  # a found sun has both
        c_az, c_el = at_photo_time(
            res.azimuth_deg, res.elevation_deg, cap.ephemeris, photo_ephemeris, sun_moves=s.sun_moves
        )
        level_az[ci] = c_az
        sig_dir = math.hypot(res.uncertainty_deg or s.centroid_sigma_deg, s.level_sigma_deg)
        pts.append(
            (ci, None if cap.yaw_deg is None else wrap_deg(c_az + cap.yaw_deg), c_el, cap.yaw_sigma_deg, sig_dir)
        )
    sun = SceneSun(found=False, captures=results, ephemeris=photo_ephemeris)
    if not pts:
        sun.flags = scene_flags + ([FlagCode.NO_SUN_FOUND.value] if any(c.blobs for c in captures) else [])
        _ephemeris_only(sun, eph_p)
        return sun
    w_el = np.array([1.0 / p[4] ** 2 for p in pts])
    el = float(np.sum(w_el * np.array([p[2] for p in pts])) / w_el.sum())
    # a capture's yaw comes with its sigma (both from the fused cues)
    with_az = cast("list[tuple[int, float, float, float, float]]", [p for p in pts if p[1] is not None])
    az = None
    az_sig = None
    if with_az:
        ww = np.array([1.0 / (p[3] ** 2 + (p[4] / max(math.cos(math.radians(el)), 0.2)) ** 2) for p in with_az])
        ang = np.radians([p[1] for p in with_az])
        az = math.degrees(math.atan2(float(np.sum(ww * np.sin(ang))), float(np.sum(ww * np.cos(ang)))))
        az_sig = 1.0 / math.sqrt(ww.sum())
    unc = math.hypot(1.0 / math.sqrt(w_el.sum()), 0.0 if az_sig is None else az_sig * math.cos(math.radians(el)))
    for ci, p_az, p_el, _, _ in pts:
        r = results[ci]
        dev_el = p_el - el
        dev_az = None if (p_az is None or az is None) else wrap_deg(p_az - az)
        yaw_sig = captures[ci].yaw_sigma_deg or 0.0
        az_tol = 3.0 * math.hypot(max(unc, 0.5), yaw_sig)
        if abs(dev_el) > el_tol or (dev_az is not None and abs(dev_az) * math.cos(math.radians(el)) > az_tol):
            detail = f"d_el {dev_el:+.2f} deg" + ("" if dev_az is None else f", d_az {dev_az:+.2f} deg")
            r.flags = [*r.flags, str(Flag(FlagCode.DISAGREES_WITH_SCENE, detail))]
            scene_flags.append(str(Flag(FlagCode.POSITION_DISAGREES, r.probe)))
    scene_el_bad = photo_ephemeris is not None and abs(el - photo_ephemeris.elevation_deg) > s.ephemeris_tolerance_deg
    for ci, p_az, p_el, _, _ in pts:
        off = _off_ephemeris(scene, ci, p_az, p_el, level_az.get(ci), scene_el_bad)
        if off is not None:
            results[ci].flags = [*results[ci].flags, off]
    sun.found, sun.azimuth_deg, sun.elevation_deg, sun.uncertainty_deg = True, az, el, unc
    sun.n_captures = len(pts)
    if az is not None and photo_heading_deg is not None:
        sun.world_azimuth_deg = solar_azimuth_from_photo(az, photo_heading_deg)
        sun.world_elevation_deg = el
        for ci, p_az, *_ in pts:
            if p_az is not None:
                results[ci].world_azimuth_deg = solar_azimuth_from_photo(p_az, photo_heading_deg)
    if photo_ephemeris is not None:
        d_el = el - photo_ephemeris.elevation_deg
        if abs(d_el) > s.ephemeris_tolerance_deg:
            scene_flags.append(
                str(
                    Flag(
                        FlagCode.EPHEMERIS_DISAGREES,
                        f"image elevation {el:.2f} deg, ephemeris {photo_ephemeris.elevation_deg:.2f} deg "
                        "(camera clock, UTC offset or GPS wrong?)",
                    )
                )
            )
        if eph_p is not None and eph_p.azimuth_deg is not None and az is not None:
            d_az = wrap_deg(az - eph_p.azimuth_deg)
            if abs(d_az) > 3.0 * s.compass_sigma_deg:
                scene_flags.append(
                    str(
                        Flag(
                            FlagCode.EPHEMERIS_AZIMUTH_DISAGREES,
                            f"{d_az:+.1f} deg ({likelier_cause(scene, abs(d_el) > s.ephemeris_tolerance_deg)})",
                        )
                    )
                )
    else:
        scene_flags.append(str(Flag(FlagCode.NO_EPHEMERIS, "the photo has no time with UTC offset or no GPS")))
    if sun.n_captures == 1 and len(captures) > 1:
        scene_flags.append(str(Flag(FlagCode.SINGLE_POSITION, "the sun was confirmed at one position only")))
    sun.flags = scene_flags
    return sun


def likelier_cause(scene: SunScene, elevation_off: bool) -> str:
    """The likelier cause of images that disagree with the ephemeris, in words: a clock, UTC offset or GPS
    where the elevation is off too (``elevation_off``: the scene's; the sun's elevation needs no compass);
    else, where the captures' compasses agree with their feature yaws (:attr:`SunScene.compasses_agree`:
    ephemeris and compasses agree with each other), the images (a mirror image of the sun in glass); where
    they disagree, the photo's compass heading."""
    if elevation_off:
        return "camera clock, UTC offset or GPS wrong?"
    agree = scene.compasses_agree
    if agree is None:
        return "clock, GPS or the photo's compass heading"
    if agree:
        return (
            "the ephemeris and the compasses agree with each other: the images are the likelier culprit, "
            "a mirror image of the sun in glass or a wrong yaw"
        )
    return "the Theta compasses disagree with the feature yaws: the photo's compass heading is the likelier culprit"


def _off_ephemeris(
    scene: SunScene, ci: int, p_az: float | None, p_el: float, level_az: float | None, scene_el_bad: bool
) -> str | None:
    """The ``sun_off_ephemeris`` flag of capture ``ci`` whose chosen sun is at ``(p_az, p_el)`` in the photo's
    frame at the photo's time (``p_az`` None: no yaw; then ``level_az``, its azimuth in the capture's level
    frame at the photo's time, through its compass, with twice the tolerance), or
    None where it agrees with the ephemeris: elevation within ``ephemeris_tolerance_deg``, azimuth within three
    compass sigmas. The flag names the likelier cause (:func:`likelier_cause`; an elevation off at this capture
    alone is the image's or its levelling's)."""
    s, eph, eph_p, cap = scene.settings, scene.photo_ephemeris, scene.ephemeris_in_photo, scene.captures[ci]
    if eph is None or eph_p is None:
        return None
    d_el = p_el - eph.elevation_deg
    d_az, route, tol = None, "", 3.0 * s.compass_sigma_deg
    if eph_p.azimuth_deg is not None:
        if p_az is not None:
            d_az, route = wrap_deg(p_az - eph_p.azimuth_deg), "through its yaw"
        elif cap.compass_yaw_deg is not None and level_az is not None:
            d_az = wrap_deg(level_az + cap.compass_yaw_deg - eph_p.azimuth_deg)
            route, tol = "through its compass", 2.0 * tol
    el_bad = abs(d_el) > s.ephemeris_tolerance_deg
    az_bad = d_az is not None and abs(d_az) > tol
    if not (el_bad or az_bad):
        return None
    parts = []
    if el_bad:
        parts.append(f"elevation {d_el:+.2f} deg")
    if d_az is not None:
        parts.append(f"azimuth {d_az:+.1f} deg")
    if el_bad and not scene_el_bad:
        cause = "this capture alone: not the sun (a glint or a reflection) or its levelling"
    else:
        cause = likelier_cause(scene, el_bad)
    how = f"{route}; " if d_az is not None else ""
    return str(Flag(FlagCode.SUN_OFF_EPHEMERIS, f"{', '.join(parts)} from the ephemeris ({how}{cause})"))


@dataclass(frozen=True)
class SunChoice:
    """:func:`choose_sun`'s result: the scene's sun, and the candidates that passed every test but
    another one fitted better (``{(probe, candidate index)}``, indices into ``CaptureSun.candidates``)."""

    sun: SceneSun
    outranked: frozenset[tuple[str, int]] = frozenset()


def choose_sun(
    captures: list[CaptureSunInput],
    *,
    photo_ephemeris: Ephemeris | None,
    photo_heading_deg: float | None,
    settings: SunSettings | None = None,
) -> SunChoice:
    """Choose the sun in every capture of a scene and form the scene's consensus (module doc), step by
    step: :func:`hard_rejections`, :func:`best_hypothesis`, :func:`choose_candidates`,
    :func:`capture_results`, :func:`with_human_labels`, :func:`consensus`.

    ``captures[i].yaw_deg``/``yaw_sigma_deg``: that capture's yaw (level -> photo panorama frame)
    from cues other than the sun (features, compass), or ``None``.
    """
    scene = SunScene(captures, photo_ephemeris, photo_heading_deg, settings or SunSettings())
    hard = hard_rejections(captures, scene.settings)
    best, hard = best_hypothesis(scene, hard)
    chosen, hard = choose_candidates(scene, best, hard)
    results, outranked = capture_results(scene, best, hard, chosen)
    sun = consensus(scene, with_human_labels(scene, results))
    return SunChoice(sun, frozenset((captures[ci].probe, bi) for ci, bi in outranked))


def scene_sun(
    captures: list[CaptureSunInput],
    *,
    photo_ephemeris: Ephemeris | None,
    photo_heading_deg: float | None,
    settings: SunSettings | None = None,
) -> SceneSun:
    """The scene's sun of :func:`choose_sun`: a :class:`SceneSun` with one :class:`CaptureSun` per capture
    (chosen and rejected candidates with reasons)."""
    return choose_sun(
        captures, photo_ephemeris=photo_ephemeris, photo_heading_deg=photo_heading_deg, settings=settings
    ).sun


def _angle_deg(az1: float, el1: float, az2: float, el2: float) -> float:
    a = direction_from_angles(np.radians(az1), np.radians(el1))
    b = direction_from_angles(np.radians(az2), np.radians(el2))
    return math.degrees(float(angular_distance(a, b)))


def _ephemeris_only(sun: SceneSun, eph_p: PhotoDirection | None) -> None:
    """A scene whose images show no sun keeps the ephemeris direction as information (found stays False)."""
    if eph_p is None:
        return
    sun.world_elevation_deg = eph_p.elevation_deg
    if sun.ephemeris is not None:
        sun.world_azimuth_deg = sun.ephemeris.azimuth_deg
